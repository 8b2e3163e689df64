// micropos web view: the state the page was served with (a JSON data
// block and the first camera image in index.html), then, once the page has
// loaded, live state from GET /api/events (server-sent events: the socket
// protocol's event lines), reads and commands through POST /api/command
// (the socket protocol's requests), the camera from GET /api/camera
// (overlay JSON) and /api/camera.png.
//
// Why nothing live starts before `load`: the event stream never ends, so
// the page is complete at `load` (what a headless screenshot captures) and
// keeps no request open until then. `?live=0` never goes live: the state
// at load and the figures, then no request at all (a still page for
// screenshots that wait for the network to go idle, and for printing).
'use strict';

const $ = (id) => document.getElementById(id);
const num = (v, digits) => (typeof v === 'number' && Number.isFinite(v)) ? v.toFixed(digits) : '–';
const LIVE = new URLSearchParams(location.search).get('live') !== '0';
const view = {
  positionUpdates: 0, cameraUpdates: 0, lastSeq: null, faults: [], jobState: null,
  lastController: null, moving: false, motionFromPositions: false, lastStatusAsk: 0,
};
// A controller position that moved more than this between two polls means
// the stage moves, µm (well above the simulator's and a C-863's noise at
// rest, well below one poll of the slowest useful move).
const MOTION_UM = 0.05;
let token = sessionStorage.getItem('micropos-token') || '';

async function command(req, withToken) {
  const headers = { 'Content-Type': 'application/json' };
  if (withToken && token) headers.Authorization = 'Bearer ' + token;
  const r = await fetch('/api/command', { method: 'POST', headers, body: JSON.stringify(req) });
  return r.json();
}

function setText(id, text) {
  const el = $(id);
  if (el && el.textContent !== text) el.textContent = text;
}

function setConn(on) {
  const c = $('conn');
  c.textContent = on ? 'live' : 'disconnected';
  c.className = 'badge ' + (on ? 'on' : 'off');
}

function bumpPositions() {
  view.positionUpdates += 1;
  $('positions').dataset.updates = String(view.positionUpdates);
}

function onPosition(p) {
  if (p.commanded) {
    setText('pos-commanded-x', num(p.commanded.x_um, 3));
    setText('pos-commanded-y', num(p.commanded.y_um, 3));
    if (p.controller) onPosition(Object.assign({ source: 'controller' }, p.controller));
    if (p.vision) onPosition(Object.assign({ source: 'vision' }, p.vision));
    return;
  }
  if (p.source === 'controller') {
    setText('pos-controller-x', num(p.x_um, 3));
    setText('pos-controller-y', num(p.y_um, 3));
    setText('pos-controller-t', 't ' + num(p.t_s, 1) + ' s');
    noteMotion(p);
  } else if (p.source === 'vision') {
    setText('pos-vision-x', num(p.stage_x_um, 3));
    setText('pos-vision-y', num(p.stage_y_um, 3));
    // Untied, the daemon sends no stage coordinates (a pattern reading is
    // no stage position): say so, with its reason, below the table.
    setText('pos-vision-q', (p.untied ? 'untied' : 'stage axes') + ' · quality ' + num(p.quality, 1) + ' bits');
    setText('pos-vision-untied', p.untied ? 'vision: ' + p.untied : '');
  }
  bumpPositions();
}

// Whether the stage moves, from consecutive controller positions: shown
// at once with the position that shows it. An axis without a position
// (not referenced, read failed) is left out; with neither axis, motion is
// unknown. The daemon's own activity (the header badge) comes with
// `status`, which has no event: it is asked for when the stage starts or
// stops moving (at most every 300 ms).
function noteMotion(p) {
  const now = [p.x_um, p.y_um].map((v) => (typeof v === 'number' && Number.isFinite(v) ? v : null));
  const last = view.lastController;
  view.lastController = now;
  if (!last) return;
  view.motionFromPositions = true;
  let known = false;
  let moving = false;
  for (let i = 0; i < 2; i++) {
    if (now[i] === null || last[i] === null) continue;
    known = true;
    if (Math.abs(now[i] - last[i]) > MOTION_UM) moving = true;
  }
  if (!known) {
    setMotion(null);
    return;
  }
  if (moving !== view.moving) {
    setMotion(moving);
    const t = performance.now();
    if (t - view.lastStatusAsk > 300) {
      view.lastStatusAsk = t;
      refreshStatus();
      if (moving) refreshPosition();
    }
  }
}

// `moving`: true, false, or null (unknown).
function setMotion(moving) {
  view.moving = moving;
  const m = $('motion');
  setText('motion', moving === null ? '–' : (moving ? 'moving' : 'at rest'));
  m.className = 'badge' + (moving ? ' moving' : '');
}

// Why a latched fault blocks motion and what clears it: the socket's
// `reset` (role admin; the CLI's `micropos reset`), after the cause is
// found. A reset does not restore a lost reference.
const RESET_HINT = 'Motion is refused until the fault is reset. Find and remove its cause, then clear it ' +
  'with `micropos reset` (socket: `{"cmd":"reset"}`, role admin). ' +
  'An axis that lost its reference then needs `micropos reference`.';

function showHint(el, text) {
  // Backticked parts as <code>, the rest as text (no HTML from strings).
  while (el.firstChild) el.removeChild(el.firstChild);
  text.split('`').forEach((part, i) => {
    if (i % 2) {
      const c = document.createElement('code');
      c.textContent = part;
      el.appendChild(c);
    } else if (part) {
      el.appendChild(document.createTextNode(part));
    }
  });
}

function onStatus(s) {
  if (s.rig) {
    setText('rig-mode', s.rig.mode || '?');
    setText('rig-activity', s.rig.activity || '?');
    const latched = s.rig.fault_latched;
    $('rig-mode').className = 'badge' + (latched ? ' fault' : '');
    $('rig-activity').className = 'badge' + (s.rig.activity === 'moving' ? ' moving' : '');
    // Until two controller positions tell, the daemon's activity does.
    if (!view.motionFromPositions) setMotion(s.rig.activity === 'moving');
    const panel = $('fault-panel');
    panel.hidden = !latched;
    if (latched) {
      setText('fault-latched', (typeof latched.t_s === 'number' ? 't ' + num(latched.t_s, 1) + ' s: ' : '') + latched.reason);
      if (!$('fault-hint').textContent) showHint($('fault-hint'), RESET_HINT);
    } else {
      setText('fault-latched', '');
    }
  }
  // The list shows events as they come; the last fault before the page
  // opened comes from `status`.
  const last = s.rig && s.rig.last_fault;
  if (last && view.faults.length === 0) onFault(Object.assign({ event: 'fault' }, last), true);
  if (s.drift) onDrift({ drift: s.drift });
  if (s.job) onJob(s.job);
}

function onJob(j) {
  if (!j || !j.kind) return;
  setText('job-kind', j.kind + (j.log ? ' ' + j.log : ''));
  setText('job-state', j.state || '');
  const done = j.done || 0;
  const total = j.total || 0;
  setText('job-done', String(done));
  setText('job-total', String(total));
  const bar = $('job-progress');
  bar.max = Math.max(total, 1);
  bar.value = done;
  setText('job-eta', typeof j.eta_s === 'number' ? formatDuration(j.eta_s) : '–');
  setText('job-error', j.error || '');
  setText('job-result', j.result ? JSON.stringify(j.result, null, 1) : '');
  if (j.result) $('job-result-box').dataset.has = '1'; else delete $('job-result-box').dataset.has;
  if (view.jobState === 'running' && j.state && j.state !== 'running') loadResults();
  view.jobState = j.state || null;
}

function formatDuration(s) {
  if (!Number.isFinite(s)) return '–';
  const h = Math.floor(s / 3600);
  const m = Math.floor((s % 3600) / 60);
  const sec = Math.floor(s % 60);
  return (h ? h + ' h ' : '') + (h || m ? m + ' min ' : '') + sec + ' s';
}

function onFault(f, fromStatus) {
  const line = (typeof f.t_s === 'number' ? num(f.t_s, 1) + ' s ' : '') + f.event +
    (f.reason ? ': ' + f.reason : '') + (f.line ? ' ' + f.line : '') + (f.state ? ' ' + f.state : '');
  view.faults.unshift(line);
  view.faults.length = Math.min(view.faults.length, 50);
  const ul = $('faults');
  const li = document.createElement('li');
  li.textContent = line;
  ul.insertBefore(li, ul.firstChild);
  while (ul.children.length > 50) ul.removeChild(ul.lastChild);
  if (!fromStatus && (f.event === 'fault' || f.event === 'reset')) refreshStatus();
}

function onDrift(d) {
  const s = d.drift || d;
  if (!s || typeof s !== 'object') return;
  if (s.method) setText('drift-method', s.method);
  const c = s.correction_um;
  setText('drift-correction', Array.isArray(c) ? num(c[0], 3) + ', ' + num(c[1], 3) : '–');
  if (typeof s.references === 'number') setText('drift-references', String(s.references));
}

function connect() {
  const es = new EventSource('/api/events');
  es.onopen = () => setConn(true);
  es.onerror = () => setConn(false);
  const on = (name, f) => es.addEventListener(name, (e) => {
    try { f(JSON.parse(e.data)); } catch (err) { /* a malformed line is skipped */ }
  });
  on('status', onStatus);
  on('position', onPosition);
  on('job', onJob);
  on('fault', onFault);
  on('drift', onDrift);
}

async function refreshStatus() {
  try {
    const s = await command({ cmd: 'status' }, false);
    if (s.ok) onStatus(s);
  } catch (e) { /* next round */ }
}

async function refreshPosition() {
  try {
    const p = await command({ cmd: 'position' }, false);
    if (p.ok) onPosition(p);
  } catch (e) { /* next round */ }
}

// FNV-1a over the image's red channel: the test (and a curious user) can
// see that the picture changed without comparing pixels.
function imageHash(ctx, w, h) {
  const d = ctx.getImageData(0, 0, w, h).data;
  let hash = 0x811c9dc5;
  for (let i = 0; i < d.length; i += 4) {
    hash ^= d[i];
    hash = Math.imul(hash, 0x01000193) >>> 0;
  }
  return hash.toString(16);
}

function drawCamera(bmp, o) {
  const c = $('camera');
  if (typeof o.width === 'number' && c.width !== o.width) c.width = o.width;
  if (typeof o.height === 'number' && c.height !== o.height) c.height = o.height;
  const ctx = c.getContext('2d', { willReadFrequently: true });
  ctx.drawImage(bmp, 0, 0);
  c.dataset.hash = imageHash(ctx, c.width, c.height);
  c.dataset.seq = String(o.sequence);
  view.cameraUpdates += 1;
  c.dataset.updates = String(view.cameraUpdates);
  const d = o.decode;
  if (d) {
    ctx.fillStyle = 'rgba(0, 255, 120, 0.9)';
    const pts = d.lattice || [];
    for (let i = 0; i + 1 < pts.length; i += 2) ctx.fillRect(pts[i] - 1.5, pts[i + 1] - 1.5, 3, 3);
    // The decoded point is the image centre; the line shows the pattern's +x.
    const cx = c.width / 2;
    const cy = c.height / 2;
    ctx.strokeStyle = 'rgba(255, 60, 60, 0.9)';
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(cx - 10, cy); ctx.lineTo(cx + 10, cy);
    ctx.moveTo(cx, cy - 10); ctx.lineTo(cx, cy + 10);
    ctx.moveTo(cx, cy);
    ctx.lineTo(cx + 40 * Math.cos(d.theta_rad), cy + 40 * Math.sin(d.theta_rad));
    ctx.stroke();
  }
  setText('cam-seq', String(o.sequence));
  setText('cam-x', d ? num(d.x_um, 3) : 'no decode');
  setText('cam-y', d ? num(d.y_um, 3) : '–');
  setText('cam-theta', d ? num(d.theta_rad * 1000, 2) : '–');
  setText('cam-quality', d ? num(d.quality, 1) : '–');
  setText('cam-coherence', d ? num(d.coherence, 2) : '–');
  setText('cam-stride', d && d.lattice_stride ? String(d.lattice_stride) : '–');
}

async function cameraTick() {
  let again = true;
  try {
    const r = await fetch('/api/camera', { cache: 'no-store' });
    const o = await r.json();
    if (o.camera === false) {
      setText('cam-seq', 'no camera configured');
      again = false;
    } else if (o.sequence !== null && o.sequence !== undefined && o.sequence !== view.lastSeq) {
      const p = await fetch('/api/camera.png?seq=' + o.sequence, { cache: 'no-store' });
      if (p.ok && p.headers.get('x-micropos-sequence') === String(o.sequence)) {
        const bmp = await createImageBitmap(await p.blob());
        drawCamera(bmp, o);
        view.lastSeq = o.sequence;
      }
    }
  } catch (e) { /* the daemon is restarting: next round */ }
  if (again) setTimeout(cameraTick, 500);
}

function fillTable(id, rows) {
  const tbody = $(id).tBodies[0];
  while (tbody.firstChild) tbody.removeChild(tbody.firstChild);
  for (const row of rows) {
    const tr = document.createElement('tr');
    for (const v of row) {
      const td = document.createElement('td');
      td.textContent = v;
      tr.appendChild(td);
    }
    tbody.appendChild(tr);
  }
}

// One `figures` reply into its panel: the summary table and the figures,
// or the daemon's reason when there is nothing to show ("no
// characterization yet: ...").
function showFigures(prefix, r) {
  const box = $(prefix + '-figures');
  if (!r.ok) {
    setText(prefix + '-status', r.error.message);
    fillTable(prefix + '-table', []);
    FIG.draw(box, []);
    box.dataset.drawn = '';
    box.dataset.panels = '0';
    return;
  }
  const notes = (r.notes || []).join('; ');
  setText(prefix + '-status', r.log + ' · ' + r.records + ' records' + (notes ? ' · ' + notes : ''));
  if (prefix === 'charact') {
    fillTable('charact-table', (r.axes || []).map((a) => [a.axis, String(a.points), String(a.cycles),
      num(a.backlash_um, 3), num(a.max_abs_error_um, 3), num(a.max_abs_coupling_um, 3), num(a.rp_max_um, 3)]));
  } else {
    fillTable('validation-table', (r.results || []).map((v) => [v.test, v.mode, String(v.poses),
      num(v.ap_max_um, 3), num(v.ap_mean_um, 3), num(v.rp_max_um, 3)]));
  }
  box.dataset.panels = String(FIG.draw(box, r.figures));
  box.dataset.drawn = r.log;
}

async function loadResults() {
  for (const [job, prefix] of [['characterize', 'charact'], ['validate', 'validation']]) {
    try {
      showFigures(prefix, await command({ cmd: 'figures', job }, false));
    } catch (e) { /* next job end */ }
  }
}

function setupControl() {
  $('token').value = token;
  $('token-form').addEventListener('submit', (e) => {
    e.preventDefault();
    token = $('token').value.trim();
    sessionStorage.setItem('micropos-token', token);
    setText('command-reply', token ? 'token set' : 'token cleared');
  });
  $('move-form').addEventListener('submit', async (e) => {
    e.preventDefault();
    const req = {
      cmd: 'move', x_um: Number($('move-x').value), y_um: Number($('move-y').value),
      mode: $('move-mode').value,
    };
    const r = await command(req, true);
    setText('command-reply', r.ok ? 'moved' : r.error.code + ': ' + r.error.message);
    refreshPosition();
  });
  $('stop').addEventListener('click', async () => {
    const r = await command({ cmd: 'stop' }, true);
    setText('command-reply', r.ok ? 'stopped' : r.error.code + ': ' + r.error.message);
  });
}

// The state the page was served with: shown before `load`, so the page
// is complete when it fires. Its camera image (`camera-first`) holds the
// `load` event until it has arrived.
function showInitial() {
  const block = $('initial-state');
  if (!block) return;
  let s;
  try { s = JSON.parse(block.textContent); } catch (e) { return; }
  if (s.status) onStatus(s.status);
  if (s.position) onPosition(s.position);
  const img = $('camera-first');
  if (s.camera && img) {
    const draw = () => {
      if (img.naturalWidth > 0 && view.lastSeq === null) {
        drawCamera(img, s.camera);
        view.lastSeq = s.camera.sequence;
      }
    };
    if (img.complete) draw(); else img.addEventListener('load', draw);
  }
}

setupControl();
showInitial();
window.addEventListener('load', () => {
  loadResults();
  if (!LIVE) {
    const c = $('conn');
    c.textContent = 'still (live=0)';
    c.className = 'badge';
    return;
  }
  connect();
  cameraTick();
  setInterval(refreshStatus, 2000);
  setInterval(refreshPosition, 2000);
});

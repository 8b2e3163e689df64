// micropos figures: draws the `figures` command's Figure data (the same
// panels `micropos plot` writes as PNG/SVG: x–y traces on linear or log
// axes, grouped bars) as inline SVG. Plain DOM, no library, no build step.
//
// Layout rules (each checked by hil-sim's web_browser test):
// - the legend sits in a band between the title and the plot area, never
//   over the data, and wraps onto more lines rather than leave the panel;
// - numbers are rounded to what they resolve: values to 0.001 (1 nm in
//   µm, the resolution the summary tables and the legends give), ticks to
//   the tick step's decimals; value labels carry the axis's unit;
// - a bar's value label is drawn upright when it fits the bar's width,
//   turned upright along the bar when not, and left out (the bar's tooltip
//   and the table beside the figure still give it) when bars are too thin
//   for even that: labels never overlap.
'use strict';

const FIG = (() => {
  const NS = 'http://www.w3.org/2000/svg';
  // plot::PALETTE, in the same order.
  const PALETTE = ['#1f77b4', '#d62728', '#2ca02c', '#ff7f0e', '#9467bd', '#646464',
    '#8c564b', '#e377c2', '#bcbd22', '#17becf'];
  const W = 560;
  const H = 280;
  // Margins around the plot area before the legend band is added to `top`.
  const M = { left: 62, right: 12, top: 24, bottom: 40 };
  // The small text of ticks, legends and values (style.css: .fig-tick,
  // .fig-value, .fig-legend text), for measuring before drawing.
  const SMALL_FONT = '10px system-ui, sans-serif';
  const LEGEND_ROW = 13;
  // Decimals a value is shown with: 0.001 µm, as in the summary tables.
  const VALUE_DECIMALS = 3;

  let measureCtx = null;
  // Width of `s` in the small font, px (a canvas measures without the
  // text being in the document).
  function textWidth(s) {
    if (!measureCtx) {
      measureCtx = document.createElement('canvas').getContext('2d');
      if (measureCtx) measureCtx.font = SMALL_FONT;
    }
    return measureCtx ? measureCtx.measureText(s).width : 6 * s.length;
  }

  function el(name, attrs, parent) {
    const e = document.createElementNS(NS, name);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, String(v));
    if (parent) parent.appendChild(e);
    return e;
  }

  function text(parent, x, y, s, attrs) {
    const t = el('text', Object.assign({ x, y }, attrs || {}), parent);
    t.textContent = s;
    return t;
  }

  const finite = (v) => typeof v === 'number' && Number.isFinite(v);

  // 1-2-5 ticks over [lo, hi], about n of them (plot::figure::linear_ticks).
  function ticks(lo, hi, n) {
    const span = hi - lo;
    if (!(span > 0)) return [lo];
    const raw = span / n;
    const mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => span / s <= n) || 10 * mag;
    const out = [];
    for (let k = Math.ceil(lo / step); k <= Math.floor(hi / step); k++) out.push(k * step);
    return out;
  }

  // Decimals that show a tick step exactly (0.25 → 2, 5 → 0).
  function stepDecimals(step) {
    if (!(step > 0)) return 0;
    for (let d = 0; d < 10; d++) {
      if (Math.abs(step * Math.pow(10, d) - Math.round(step * Math.pow(10, d))) < 1e-6) return d;
    }
    return 10;
  }

  // Tick labels of one axis, each with the decimals of the step.
  function tickLabeller(ts) {
    const step = ts.length > 1 ? Math.abs(ts[1] - ts[0]) : 0;
    const d = stepDecimals(step);
    return (v) => {
      const a = Math.abs(v);
      if (a !== 0 && (a >= 1e6 || a < 1e-4)) return v.toExponential(0);
      return (Math.abs(v) < 0.5 * Math.pow(10, -d) ? 0 : v).toFixed(d);
    };
  }

  // A value rounded to its resolution (26.99251 → "26.993", 0.0510548 →
  // "0.051").
  function value(v) {
    return v.toFixed(VALUE_DECIMALS);
  }

  // The unit of an axis label: "AP (µm)" → "µm", a bare "µm" → itself.
  function unitOf(axisLabel) {
    const m = /\(([^()]+)\)\s*$/.exec(axisLabel || '');
    if (m) return m[1];
    const s = (axisLabel || '').trim();
    return s && !/\s/.test(s) && s.length <= 4 ? s : '';
  }

  // Legend entries laid out in rows across the plot's width: returns the
  // placed entries and the band's height.
  function layoutLegend(entries) {
    const left = M.left;
    const right = W - M.right;
    const placed = [];
    let x = left;
    let row = 0;
    for (const [name, colour] of entries) {
      const w = 16 + textWidth(name);
      if (x > left && x + w > right) {
        row += 1;
        x = left;
      }
      placed.push({ name, colour, x, row, w });
      x += w + 14;
    }
    return { placed, height: entries.length ? (row + 1) * LEGEND_ROW + 4 : 0 };
  }

  function drawLegend(svg, layout) {
    if (!layout.placed.length) return;
    const g = el('g', { class: 'fig-legend' }, svg);
    for (const e of layout.placed) {
      const y = M.top + e.row * LEGEND_ROW + 9;
      el('rect', { x: e.x, y: y - 8, width: 12, height: 8, fill: e.colour }, g);
      // Long names are cut to the panel's width (the whole name stays the
      // element's tooltip).
      const room = W - M.right - (e.x + 16);
      let name = e.name;
      while (name.length > 1 && textWidth(name) > room) name = name.slice(0, -2) + '…';
      const t = text(g, e.x + 16, y, name);
      if (name !== e.name) el('title', {}, t).textContent = e.name;
    }
  }

  function frame(svg, title, xLabel, yLabel, top) {
    text(svg, W / 2, 15, title, { 'text-anchor': 'middle', class: 'fig-title' });
    text(svg, (M.left + W - M.right) / 2, H - 6, xLabel, { 'text-anchor': 'middle', class: 'fig-label' });
    const y = (top + H - M.bottom) / 2;
    text(svg, 12, y, yLabel, { 'text-anchor': 'middle', class: 'fig-label', transform: `rotate(-90 12 ${y})` });
  }

  function axes(svg, top, sx, sy, xt, yt, xLabelOf, yLabelOf) {
    const g = el('g', { class: 'fig-axes' }, svg);
    for (const t of xt) {
      const x = sx(t);
      el('line', { x1: x, x2: x, y1: top, y2: H - M.bottom, class: 'fig-grid' }, g);
      text(g, x, H - M.bottom + 14, xLabelOf(t), { 'text-anchor': 'middle', class: 'fig-tick' });
    }
    for (const t of yt) {
      const y = sy(t);
      el('line', { x1: M.left, x2: W - M.right, y1: y, y2: y, class: 'fig-grid' }, g);
      text(g, M.left - 4, y + 4, yLabelOf(t), { 'text-anchor': 'end', class: 'fig-tick' });
    }
    el('rect', { x: M.left, y: top, width: W - M.left - M.right, height: H - top - M.bottom, class: 'fig-box' }, g);
  }

  function range(values) {
    let lo = Infinity;
    let hi = -Infinity;
    for (const v of values) {
      if (finite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    }
    if (!finite(lo)) return [0, 1];
    if (hi - lo <= 0) return [lo - 0.5, hi + 0.5];
    const pad = 0.04 * (hi - lo);
    return [lo - pad, hi + pad];
  }

  function xyPanel(p) {
    const svg = el('svg', { viewBox: `0 0 ${W} ${H}`, width: W, height: H, class: 'fig-panel', 'data-kind': 'xy' });
    const log = p.y_scale === 'log';
    const ty = (v) => (log ? (finite(v) && v > 0 ? Math.log10(v) : NaN) : v);
    const entries = p.traces
      .filter((t) => t.label)
      .map((t) => [t.label, PALETTE[t.color % PALETTE.length]]);
    const legend = layoutLegend(entries);
    const top = M.top + legend.height;
    const xs = [];
    const ys = [];
    for (const t of p.traces) {
      for (const pt of t.points) {
        if (pt && finite(pt[0]) && finite(ty(pt[1]))) { xs.push(pt[0]); ys.push(ty(pt[1])); }
      }
    }
    let [x0, x1] = range(xs);
    let [y0, y1] = range(ys);
    const pw = W - M.left - M.right;
    const ph = H - top - M.bottom;
    if (p.equal_aspect && !log) {
      // Same µm per pixel on both axes: widen the tighter one.
      const k = Math.max((x1 - x0) / pw, (y1 - y0) / ph);
      const cx = (x0 + x1) / 2;
      const cy = (y0 + y1) / 2;
      [x0, x1] = [cx - k * pw / 2, cx + k * pw / 2];
      [y0, y1] = [cy - k * ph / 2, cy + k * ph / 2];
    }
    const sx = (v) => M.left + (v - x0) / (x1 - x0) * pw;
    const sy = (v) => H - M.bottom - (v - y0) / (y1 - y0) * ph;
    frame(svg, p.title, p.x_label, p.y_label, top);
    const xt = ticks(x0, x1, 8);
    const yt = log
      ? ticks(Math.floor(y0), Math.ceil(y1), 8).filter((t) => t >= y0 && t <= y1 && Number.isInteger(t))
      : ticks(y0, y1, 6);
    // A decade 10^k is written with k's decimals (0.01, 1, 100).
    const logLabel = (t) => Math.pow(10, t).toFixed(Math.max(0, -t));
    axes(svg, top, sx, sy, xt, yt, tickLabeller(xt), log ? logLabel : tickLabeller(yt));
    let marks = 0;
    for (const t of p.traces) {
      const colour = PALETTE[t.color % PALETTE.length];
      const g = el('g', { stroke: colour, fill: colour, class: 'fig-data' }, svg);
      const pts = t.points
        .filter((pt) => pt && finite(pt[0]) && finite(ty(pt[1])))
        .map((pt) => [sx(pt[0]), sy(ty(pt[1]))]);
      if (t.style === 'line' || t.style === 'line_dots') {
        el('polyline', { points: pts.map((q) => q[0].toFixed(1) + ',' + q[1].toFixed(1)).join(' '), fill: 'none', 'stroke-width': 1.2 }, g);
        marks += 1;
      }
      if (t.style === 'dots' || t.style === 'line_dots') {
        for (const q of pts) el('circle', { cx: q[0].toFixed(1), cy: q[1].toFixed(1), r: 2 }, g);
        marks += pts.length;
      }
      if (t.style === 'crosses') {
        const d = pts.map((q) => `M${q[0] - 4},${q[1]}h8M${q[0]},${q[1] - 4}v8`).join('');
        el('path', { d, fill: 'none', 'stroke-width': 1.2 }, g);
        marks += pts.length;
      }
    }
    drawLegend(svg, legend);
    svg.dataset.marks = String(marks);
    return svg;
  }

  function barPanel(p) {
    const svg = el('svg', { viewBox: `0 0 ${W} ${H}`, width: W, height: H, class: 'fig-panel', 'data-kind': 'bars' });
    const legend = layoutLegend(p.groups.map((g) => [g.label, PALETTE[g.color % PALETTE.length]]));
    const top = M.top + legend.height;
    frame(svg, p.title, p.x_label, p.y_label, top);
    const unit = unitOf(p.y_label);
    const labelOf = (v) => value(v) + (unit ? ' ' + unit : '');
    // The value as the figure data prints it (rounded to its resolution,
    // with its unit), else rounded here.
    const shownOf = (grp, i, v) => (grp.value_labels && grp.value_labels[i]) || labelOf(v);
    const values = p.groups.flatMap((g) => g.values).filter(finite);
    const pw = W - M.left - M.right;
    const ph = H - top - M.bottom;
    const slot = pw / Math.max(p.categories.length, 1);
    const bw = Math.max(2, (slot - 10) / Math.max(p.groups.length, 1));
    // How each value label is drawn: across the bar when it fits its
    // width, along it when the bar is at least a line of text wide, else
    // not at all.
    const widest = p.groups.reduce((m, grp) => grp.values.reduce(
      (w, v, i) => (finite(v) ? Math.max(w, textWidth(shownOf(grp, i, v))) : w), m), 0);
    const mode = widest + 2 <= bw ? 'across' : (bw >= 11 ? 'along' : 'none');
    // Room above the tallest bar for its label.
    const room = mode === 'across' ? 14 : (mode === 'along' ? widest + 6 : 4);
    const hi = values.length ? Math.max(...values, 0) : 1;
    const top0 = hi > 0 ? hi * ph / Math.max(ph - room, 1) : 1;
    const yt = ticks(0, top0, 5);
    const sy = (v) => H - M.bottom - v / top0 * ph;
    axes(svg, top, () => M.left, sy, [], yt, String, tickLabeller(yt));
    let marks = 0;
    const g = el('g', { class: 'fig-data' }, svg);
    const labels = el('g', { class: 'fig-values' }, svg);
    p.categories.forEach((c, ci) => {
      text(svg, M.left + ci * slot + slot / 2, H - M.bottom + 14, c, { 'text-anchor': 'middle', class: 'fig-tick' });
      p.groups.forEach((grp, gi) => {
        const v = grp.values[ci];
        if (!finite(v)) return;
        const x = M.left + ci * slot + 5 + gi * bw;
        const y = sy(Math.max(v, 0));
        const bar = el('rect', { x, y, width: Math.max(bw - 1, 1), height: Math.max(H - M.bottom - y, 0), fill: PALETTE[grp.color % PALETTE.length] }, g);
        const shown = shownOf(grp, ci, v);
        el('title', {}, bar).textContent = `${grp.label}, ${c}: ${shown}`;
        const cx = x + bw / 2;
        if (mode === 'across') {
          text(labels, cx, y - 3, shown, { 'text-anchor': 'middle', class: 'fig-value' });
        } else if (mode === 'along') {
          text(labels, cx + 3.5, y - 3, shown, { 'text-anchor': 'start', class: 'fig-value', transform: `rotate(-90 ${cx + 3.5} ${y - 3})` });
        }
        marks += 1;
      });
    });
    drawLegend(svg, legend);
    svg.dataset.marks = String(marks);
    svg.dataset.values = mode;
    return svg;
  }

  // Replaces the content of `container` with `figures`; returns the
  // number of panels drawn.
  function draw(container, figures) {
    while (container.firstChild) container.removeChild(container.firstChild);
    let panels = 0;
    for (const f of figures || []) {
      const div = document.createElement('div');
      div.className = 'figure';
      const h = document.createElement('h3');
      h.textContent = f.title;
      div.appendChild(h);
      for (const row of f.rows || []) {
        const r = document.createElement('div');
        r.className = 'figure-row';
        for (const p of row) {
          r.appendChild(p.kind === 'bars' ? barPanel(p) : xyPanel(p));
          panels += 1;
        }
        div.appendChild(r);
      }
      container.appendChild(div);
    }
    return panels;
  }

  return { draw, value, unitOf };
})();

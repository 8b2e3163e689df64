// micropos figures: draws the `figures` command's Figure data (the same
// panels `micropos plot` writes as PNG/SVG: x–y traces on linear or log
// axes, grouped bars) as inline SVG. Plain DOM, no library, no build step.
'use strict';

const FIG = (() => {
  const NS = 'http://www.w3.org/2000/svg';
  // plot::PALETTE, in the same order.
  const PALETTE = ['#1f77b4', '#d62728', '#2ca02c', '#ff7f0e', '#9467bd', '#646464',
    '#8c564b', '#e377c2', '#bcbd22', '#17becf'];
  const W = 560;
  const H = 280;
  const M = { left: 62, right: 12, top: 26, bottom: 40 };

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

  function label(v) {
    const a = Math.abs(v);
    if (a !== 0 && (a >= 1e5 || a < 1e-3)) return v.toExponential(1);
    return String(Number(v.toPrecision(6)));
  }

  function frame(svg, title, xLabel, yLabel) {
    text(svg, W / 2, 16, title, { 'text-anchor': 'middle', class: 'fig-title' });
    text(svg, (M.left + W - M.right) / 2, H - 6, xLabel, { 'text-anchor': 'middle', class: 'fig-label' });
    const y = (M.top + H - M.bottom) / 2;
    text(svg, 12, y, yLabel, { 'text-anchor': 'middle', class: 'fig-label', transform: `rotate(-90 12 ${y})` });
  }

  function axes(svg, sx, sy, xt, yt, yLabelOf) {
    const g = el('g', { class: 'fig-axes' }, svg);
    for (const t of xt) {
      const x = sx(t);
      el('line', { x1: x, x2: x, y1: M.top, y2: H - M.bottom, class: 'fig-grid' }, g);
      text(g, x, H - M.bottom + 14, label(t), { 'text-anchor': 'middle', class: 'fig-tick' });
    }
    for (const t of yt) {
      const y = sy(t);
      el('line', { x1: M.left, x2: W - M.right, y1: y, y2: y, class: 'fig-grid' }, g);
      text(g, M.left - 4, y + 4, yLabelOf(t), { 'text-anchor': 'end', class: 'fig-tick' });
    }
    el('rect', { x: M.left, y: M.top, width: W - M.left - M.right, height: H - M.top - M.bottom, class: 'fig-box' }, g);
  }

  function legend(svg, entries) {
    let y = M.top + 12;
    for (const [name, colour] of entries) {
      el('rect', { x: W - M.right - 150, y: y - 8, width: 12, height: 8, fill: colour }, svg);
      text(svg, W - M.right - 134, y, name, { class: 'fig-tick' });
      y += 13;
    }
  }

  function xyPanel(p) {
    const svg = el('svg', { viewBox: `0 0 ${W} ${H}`, width: W, height: H, class: 'fig-panel', 'data-kind': 'xy' });
    const log = p.y_scale === 'log';
    const ty = (v) => (log ? (finite(v) && v > 0 ? Math.log10(v) : NaN) : v);
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
    const ph = H - M.top - M.bottom;
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
    frame(svg, p.title, p.x_label, p.y_label);
    const yt = log
      ? ticks(Math.floor(y0), Math.ceil(y1), 8).filter((t) => t >= y0 && t <= y1 && Number.isInteger(t))
      : ticks(y0, y1, 6);
    axes(svg, sx, sy, ticks(x0, x1, 8), yt, (t) => (log ? label(Math.pow(10, t)) : label(t)));
    const entries = [];
    let marks = 0;
    for (const t of p.traces) {
      const colour = PALETTE[t.color % PALETTE.length];
      const g = el('g', { stroke: colour, fill: colour }, svg);
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
      if (t.label) entries.push([t.label, colour]);
    }
    legend(svg, entries);
    svg.dataset.marks = String(marks);
    return svg;
  }

  function barPanel(p) {
    const svg = el('svg', { viewBox: `0 0 ${W} ${H}`, width: W, height: H, class: 'fig-panel', 'data-kind': 'bars' });
    frame(svg, p.title, p.x_label, p.y_label);
    const values = p.groups.flatMap((g) => g.values).filter(finite);
    const top = values.length ? Math.max(...values) * 1.15 : 1;
    const pw = W - M.left - M.right;
    const ph = H - M.top - M.bottom;
    const sy = (v) => H - M.bottom - v / top * ph;
    axes(svg, () => M.left, sy, [], ticks(0, top, 5), label);
    const slot = pw / Math.max(p.categories.length, 1);
    const bw = Math.max(2, (slot - 10) / Math.max(p.groups.length, 1));
    let marks = 0;
    p.categories.forEach((c, ci) => {
      text(svg, M.left + ci * slot + slot / 2, H - M.bottom + 14, c, { 'text-anchor': 'middle', class: 'fig-tick' });
      p.groups.forEach((g, gi) => {
        const v = g.values[ci];
        if (!finite(v)) return;
        const x = M.left + ci * slot + 5 + gi * bw;
        el('rect', { x, y: sy(v), width: bw - 1, height: H - M.bottom - sy(v), fill: PALETTE[g.color % PALETTE.length] }, svg);
        // The value as the figure data prints it (rounded, with its unit).
        const shown = (g.value_labels && g.value_labels[ci]) || label(v);
        text(svg, x + bw / 2, sy(v) - 3, shown, { 'text-anchor': 'middle', class: 'fig-value' });
        marks += 1;
      });
    });
    legend(svg, p.groups.map((g) => [g.label, PALETTE[g.color % PALETTE.length]]));
    svg.dataset.marks = String(marks);
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

  return { draw };
})();

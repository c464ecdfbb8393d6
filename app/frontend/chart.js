// A small strip chart on a canvas: line series, a dashed threshold, shaded takeover intervals,
// episode boundaries and a replay cursor. No dependencies; redraws at most once per animation frame.
"use strict";

class StripChart {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {{series: {key: string, label: string, color: string, width?: number, dash?: number[], fill?: boolean}[],
   *          yMin?: number, yMax?: number, bandColors?: Record<string, string>, title?: string}} options
   */
  constructor(canvas, options) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.options = options;
    this.x = [];
    this.values = Object.fromEntries(options.series.map((s) => [s.key, []]));
    this.actors = [];
    this.boundaries = [];
    this.cursor = null;
    this.window = null; // number of points shown (null: all)
    this.dirty = true;
    this.frames = 0;
    this.emptyText = "";
    this._loop = this._loop.bind(this);
    requestAnimationFrame(this._loop);
    new ResizeObserver(() => { this.dirty = true; }).observe(canvas);
  }

  clear() {
    this.x = [];
    for (const key of Object.keys(this.values)) this.values[key] = [];
    this.actors = [];
    this.boundaries = [];
    this.cursor = null;
    this.dirty = true;
  }

  /** Append one point; `actor` non-null marks a takeover step (shaded). */
  push(x, point, actor, boundary, limit) {
    this.x.push(x);
    for (const s of this.options.series) this.values[s.key].push(point[s.key] ?? null);
    this.actors.push(actor);
    if (boundary) this.boundaries.push(x);
    if (limit && this.x.length > limit) {
      const drop = this.x.length - limit;
      this.x.splice(0, drop);
      for (const key of Object.keys(this.values)) this.values[key].splice(0, drop);
      this.actors.splice(0, drop);
      const first = this.x[0];
      this.boundaries = this.boundaries.filter((b) => b >= first);
    }
    this.dirty = true;
  }

  setAll(x, values, actors) {
    this.x = x.slice();
    for (const s of this.options.series) this.values[s.key] = (values[s.key] || []).slice();
    this.actors = actors.slice();
    this.boundaries = [];
    this.dirty = true;
  }

  setCursor(x) {
    this.cursor = x;
    this.dirty = true;
  }

  _loop() {
    if (this.dirty) {
      this.dirty = false;
      this.draw();
      this.frames += 1;
    }
    requestAnimationFrame(this._loop);
  }

  draw() {
    const { canvas, ctx, options } = this;
    const dpr = window.devicePixelRatio || 1;
    const cssW = canvas.clientWidth;
    const cssH = canvas.clientHeight;
    if (cssW === 0 || cssH === 0) return;
    if (canvas.width !== Math.round(cssW * dpr) || canvas.height !== Math.round(cssH * dpr)) {
      canvas.width = Math.round(cssW * dpr);
      canvas.height = Math.round(cssH * dpr);
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, cssW, cssH);
    const pad = { left: 50, right: 12, top: 26, bottom: 22 };
    const w = cssW - pad.left - pad.right;
    const h = cssH - pad.top - pad.bottom;
    const n = this.x.length;

    // y range: fixed bounds widened by the data, but robust: a few outliers (one fear spike of 40 among
    // values near 0.5) would flatten every other point, so the range stops at the inner quantiles
    // stretched by their spread, and points beyond it are drawn on the edge with a marker.
    const finite = [];
    for (const s of options.series) {
      for (const v of this.values[s.key]) if (v !== null && Number.isFinite(v)) finite.push(v);
    }
    let lo = options.yMin ?? Infinity;
    let hi = options.yMax ?? -Infinity;
    if (finite.length) {
      const sorted = finite.slice().sort((a, b) => a - b);
      const q = (p) => sorted[Math.min(sorted.length - 1, Math.max(0, Math.round(p * (sorted.length - 1))))];
      const [qLo, qHi] = sorted.length >= 20 ? [q(0.02), q(0.98)] : [sorted[0], sorted[sorted.length - 1]];
      const spread = Math.max(qHi - qLo, 1e-6);
      lo = Math.min(lo, Math.max(sorted[0], qLo - spread));
      hi = Math.max(hi, Math.min(sorted[sorted.length - 1], qHi + spread));
    }
    if (!Number.isFinite(lo) || !Number.isFinite(hi)) { lo = 0; hi = 1; }
    if (hi - lo < 1e-6) { hi = lo + 1; }
    const span = hi - lo;
    hi += span * 0.08;
    if (options.yMin === undefined) lo -= span * 0.04;
    const clipped = finite.filter((v) => v > hi || v < lo).length;
    this.range = { lo, hi, clipped }; // for tests

    const x0 = n ? this.x[0] : 0;
    const x1 = n ? Math.max(this.x[n - 1], x0 + (this.window || 1) - 1) : 1;
    const sx = (x) => pad.left + ((x - x0) / Math.max(x1 - x0, 1)) * w;
    const sy = (v) => pad.top + (1 - (v - lo) / (hi - lo)) * h;

    // grid and y ticks
    ctx.font = "13px ui-monospace, SFMono-Regular, Menlo, Consolas, monospace";
    ctx.fillStyle = "#7d8b9c";
    ctx.strokeStyle = "rgba(148,163,184,0.10)";
    ctx.lineWidth = 1;
    const ticks = niceTicks(lo, hi, Math.max(2, Math.min(5, Math.floor(h / 32))));
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    for (const t of ticks) {
      const y = Math.round(sy(t)) + 0.5;
      ctx.beginPath(); ctx.moveTo(pad.left, y); ctx.lineTo(pad.left + w, y); ctx.stroke();
      ctx.fillText(formatTick(t), pad.left - 6, y);
    }
    // x ticks
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    for (const t of niceTicks(x0, x1, 6)) {
      if (t < x0 || t > x1) continue;
      ctx.fillText(String(Math.round(t)), sx(t), pad.top + h + 5);
    }
    ctx.textAlign = "right"; // the x axis counts loop steps; say so where the y labels end
    ctx.fillText("step", pad.left - 6, pad.top + h + 5);

    // shaded takeover intervals, coloured by who acted
    const bandColors = options.bandColors || {};
    const step = n > 1 ? (sx(this.x[n - 1]) - sx(x0)) / (n - 1) : w;
    let i = 0;
    while (i < n) {
      const actor = this.actors[i];
      if (!actor) { i += 1; continue; }
      let j = i;
      while (j + 1 < n && this.actors[j + 1] === actor) j += 1;
      ctx.fillStyle = bandColors[actor] || "rgba(245,158,11,0.18)";
      const left = sx(this.x[i]) - step / 2;
      ctx.fillRect(Math.max(pad.left, left), pad.top, Math.min(sx(this.x[j]) + step / 2, pad.left + w) - Math.max(pad.left, left), h);
      i = j + 1;
    }

    // episode boundaries
    ctx.strokeStyle = "rgba(148,163,184,0.35)";
    ctx.setLineDash([2, 3]);
    for (const b of this.boundaries) {
      const x = Math.round(sx(b)) + 0.5;
      ctx.beginPath(); ctx.moveTo(x, pad.top); ctx.lineTo(x, pad.top + h); ctx.stroke();
    }
    ctx.setLineDash([]);

    // series
    for (const s of options.series) {
      const values = this.values[s.key];
      ctx.strokeStyle = s.color;
      ctx.lineWidth = s.width || 1.6;
      ctx.setLineDash(s.dash || []);
      ctx.lineJoin = "round";
      ctx.beginPath();
      let pen = false;
      for (let k = 0; k < n; k++) {
        const v = values[k];
        if (v === null || !Number.isFinite(v)) { pen = false; continue; }
        const px = sx(this.x[k]);
        const py = sy(Math.min(hi, Math.max(lo, v)));
        if (pen) ctx.lineTo(px, py); else ctx.moveTo(px, py);
        pen = true;
      }
      ctx.stroke();
      if (s.fill && n > 1) {
        ctx.setLineDash([]);
        const grad = ctx.createLinearGradient(0, pad.top, 0, pad.top + h);
        grad.addColorStop(0, s.color + "55");
        grad.addColorStop(1, s.color + "00");
        ctx.fillStyle = grad;
        ctx.beginPath();
        let started = false;
        let lastX = 0;
        for (let k = 0; k < n; k++) {
          const v = values[k];
          if (v === null || !Number.isFinite(v)) continue;
          const px = sx(this.x[k]);
          if (!started) { ctx.moveTo(px, sy(lo)); started = true; }
          ctx.lineTo(px, sy(Math.min(hi, Math.max(lo, v))));
          lastX = px;
        }
        if (started) { ctx.lineTo(lastX, sy(lo)); ctx.closePath(); ctx.fill(); }
      }
    }
    ctx.setLineDash([]);
    if (clipped) { // outliers are drawn on the edge; say so, so that nobody reads the edge as their value
      ctx.fillStyle = "#fbbf24";
      ctx.textAlign = "right";
      ctx.textBaseline = "top";
      ctx.fillText(`▲ ${clipped} off scale`, pad.left + w, pad.top + 2);
    }

    // replay cursor
    if (this.cursor !== null && n) {
      const x = Math.round(sx(this.cursor)) + 0.5;
      ctx.strokeStyle = "#e2e8f0";
      ctx.lineWidth = 1.5;
      ctx.beginPath(); ctx.moveTo(x, pad.top - 4); ctx.lineTo(x, pad.top + h); ctx.stroke();
    }

    // title and legend with the newest values
    ctx.textBaseline = "middle";
    ctx.textAlign = "left";
    let lx = pad.left;
    if (options.title) {
      ctx.font = "600 12px system-ui, -apple-system, Segoe UI, sans-serif";
      ctx.fillStyle = "#cbd5e1";
      ctx.fillText(options.title, lx, 12);
      lx += ctx.measureText(options.title).width + 16;
    }
    ctx.font = "13px ui-monospace, SFMono-Regular, Menlo, Consolas, monospace";
    const at = this.cursor !== null ? this.x.indexOf(this.cursor) : n - 1;
    for (const s of options.series) {
      const v = at >= 0 ? this.values[s.key][at] : null;
      ctx.strokeStyle = s.color;
      ctx.lineWidth = 2;
      ctx.setLineDash(s.dash || []);
      ctx.beginPath(); ctx.moveTo(lx, 12); ctx.lineTo(lx + 14, 12); ctx.stroke();
      ctx.setLineDash([]);
      ctx.fillStyle = "#94a3b8";
      const text = `${s.label} ${v === null || v === undefined || !Number.isFinite(v) ? "–" : v.toFixed(3)}`;
      ctx.fillText(text, lx + 18, 12);
      lx += 18 + ctx.measureText(text).width + 14;
    }
    const note = n && !this.emptyText && options.note ? options.note(this) : null;
    if (note) { // a flat line explained where it is drawn (e.g. fear near zero while nothing is close)
      ctx.fillStyle = "#94a3b8";
      ctx.textAlign = "center";
      ctx.textBaseline = "middle";
      ctx.font = "13px system-ui, sans-serif";
      ctx.fillText(note, pad.left + w / 2, pad.top + h / 2);
    }
    if (!n || this.emptyText) {
      ctx.fillStyle = "#64748b";
      ctx.textAlign = "center";
      ctx.font = "12px system-ui, sans-serif";
      ctx.fillText(this.emptyText || "waiting for data…", pad.left + w / 2, pad.top + h / 2);
    }
  }
}

function niceTicks(lo, hi, count) {
  const span = hi - lo;
  if (!(span > 0)) return [lo];
  const raw = span / count;
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const norm = raw / mag;
  const step = (norm >= 5 ? 5 : norm >= 2 ? 2 : 1) * mag;
  const out = [];
  for (let t = Math.ceil(lo / step) * step; t <= hi + 1e-9; t += step) out.push(Number(t.toFixed(10)));
  return out;
}

function formatTick(t) {
  if (Math.abs(t) >= 100) return t.toFixed(0);
  if (Math.abs(t) >= 10) return t.toFixed(1);
  return t.toFixed(2);
}

window.StripChart = StripChart;

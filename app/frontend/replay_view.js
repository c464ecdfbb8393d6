// A page's own view of a replayed episode: the recorded scene drawn top-down on a canvas over the 3D view.
// The 3D view is one viser scene that every page shares and it keeps showing the live run, so a replay is
// drawn here, for this page only (the scene format is core/scene.py: boxes, circles, polylines, polygons,
// the ego, the goal, lidar rays; world metres, x east, y north).
"use strict";

class ReplayView {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.static = null;
    this.frames = 0; // frames drawn (tests read it)
  }

  setStatic(staticScene) { this.static = staticScene || null; }

  // world -> canvas: fit the scene's bounds, keep the aspect ratio, y up
  _transform(bounds, width, height) {
    const [x0, y0, x1, y1] = bounds && bounds.length === 4 ? bounds : [0, 0, 10, 6];
    const margin = 12;
    const scale = Math.max(1e-6, Math.min((width - 2 * margin) / Math.max(x1 - x0, 1e-6), (height - 2 * margin) / Math.max(y1 - y0, 1e-6)));
    const ox = (width - scale * (x1 - x0)) / 2 - scale * x0;
    const oy = (height + scale * (y1 - y0)) / 2 + scale * y0;
    return { scale, px: (x) => ox + scale * x, py: (y) => oy - scale * y };
  }

  _shape(s, t, fallback) {
    const ctx = this.ctx;
    ctx.fillStyle = ctx.strokeStyle = s.color || fallback;
    if (s.kind === "box") {
      const c = Math.cos(s.yaw || 0), n = Math.sin(s.yaw || 0), hl = s.length / 2, hw = s.width / 2;
      ctx.beginPath();
      for (const [a, b] of [[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]]) ctx.lineTo(t.px(s.x + c * a - n * b), t.py(s.y + n * a + c * b));
      ctx.closePath(); ctx.fill();
    } else if (s.kind === "circle") {
      ctx.beginPath(); ctx.arc(t.px(s.x), t.py(s.y), Math.max(1, t.scale * s.radius), 0, 2 * Math.PI); ctx.fill();
    } else if ((s.kind === "polyline" || s.kind === "polygon") && s.points && s.points.length) {
      ctx.beginPath();
      for (const [x, y] of s.points) ctx.lineTo(t.px(x), t.py(y));
      if (s.kind === "polygon") { ctx.closePath(); ctx.globalAlpha = 0.35; ctx.fill(); ctx.globalAlpha = 1; }
      else { if (s.closed) ctx.closePath(); ctx.lineWidth = Math.max(1, t.scale * (s.width || 0.05)); ctx.stroke(); }
    }
  }

  // draw one recorded frame; ``trail`` is the ego's [x, y] path up to it
  draw(scene, trail) {
    const canvas = this.canvas, ctx = this.ctx;
    const ratio = window.devicePixelRatio || 1;
    const width = canvas.clientWidth, height = canvas.clientHeight;
    if (canvas.width !== Math.round(width * ratio) || canvas.height !== Math.round(height * ratio)) {
      canvas.width = Math.round(width * ratio); canvas.height = Math.round(height * ratio);
    }
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    ctx.fillStyle = "#0b1117"; ctx.fillRect(0, 0, width, height);
    if (!scene) { this.frames += 1; return; }
    const bounds = (this.static && this.static.bounds) || scene.bounds;
    const t = this._transform(bounds, width, height);
    for (const s of (this.static && this.static.static) || scene.static || []) this._shape(s, t, "#475569");
    if (scene.goal) this._shape({ ...scene.goal, color: scene.goal.color || "#2dd4bf" }, t, "#2dd4bf");
    const rays = scene.rays;
    if (rays && rays.ends) {
      ctx.lineWidth = 1; ctx.strokeStyle = "rgba(56,189,248,0.18)";
      ctx.beginPath();
      for (const [x, y] of rays.ends) { ctx.moveTo(t.px(rays.origin[0]), t.py(rays.origin[1])); ctx.lineTo(t.px(x), t.py(y)); }
      ctx.stroke();
    }
    for (const s of scene.movers || []) this._shape(s, t, "#f97316");
    if (trail && trail.length > 1) {
      ctx.lineWidth = 2; ctx.strokeStyle = "rgba(52,211,153,0.7)";
      ctx.beginPath();
      for (const [x, y] of trail) ctx.lineTo(t.px(x), t.py(y));
      ctx.stroke();
    }
    if (scene.ego) this._shape(scene.ego, t, "#34d399");
    this.frames += 1;
  }
}
window.ReplayView = ReplayView;

// The imagined horizon: for the current step, each ensemble member's predicted violation probability over the
// next m steps of its own rollout under the policy (thin lines), their mean (thick) and the members' spread
// (the band) — what fear is made of, drawn as the gate computed it (live, and in replay from the session).
"use strict";

class HorizonChart {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.drawn = 0; // frames drawn (tests read it)
    this.last = null;
  }

  draw(horizon) {
    this.last = horizon || null;
    const canvas = this.canvas, ctx = this.ctx;
    const ratio = window.devicePixelRatio || 1;
    const width = canvas.clientWidth, height = canvas.clientHeight;
    if (!width || !height) return;
    if (canvas.width !== Math.round(width * ratio)) { canvas.width = Math.round(width * ratio); canvas.height = Math.round(height * ratio); }
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    ctx.clearRect(0, 0, width, height);
    ctx.strokeStyle = "rgba(125,139,156,0.35)"; ctx.lineWidth = 1;
    ctx.strokeRect(0.5, 0.5, width - 1, height - 1);
    if (!horizon || !horizon.cost || !horizon.cost.length) { this.drawn += 1; return; }
    const m = horizon.cost.length;
    const x = (k) => 4 + (m > 1 ? (k / (m - 1)) * (width - 8) : 0);
    const y = (p) => height - 3 - Math.max(0, Math.min(1, p)) * (height - 6);
    ctx.fillStyle = "rgba(251,113,133,0.22)";
    ctx.beginPath();
    horizon.mean.forEach((mu, k) => ctx.lineTo(x(k), y(mu + horizon.spread[k])));
    for (let k = m - 1; k >= 0; k--) ctx.lineTo(x(k), y(horizon.mean[k] - horizon.spread[k]));
    ctx.closePath(); ctx.fill();
    const members = horizon.cost[0].length;
    ctx.strokeStyle = "rgba(251,113,133,0.55)"; ctx.lineWidth = 1;
    for (let n = 0; n < members; n++) {
      ctx.beginPath();
      horizon.cost.forEach((row, k) => ctx.lineTo(x(k), y(row[n])));
      ctx.stroke();
    }
    ctx.strokeStyle = "#fb7185"; ctx.lineWidth = 2;
    ctx.beginPath();
    horizon.mean.forEach((mu, k) => ctx.lineTo(x(k), y(mu)));
    ctx.stroke();
    this.drawn += 1;
  }
}
window.HorizonChart = HorizonChart;

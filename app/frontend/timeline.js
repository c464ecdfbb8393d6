// The replay's session timeline (Foxglove/Rerun-style): a state lane (who drove each step: agent, person,
// fallback, scripted expert) and event markers from the session store (gate firing, takeover start and end,
// violation, collision, the episode's end and why, and the fine-tuned version when it changed). Clicking seeks the replay to the nearest event, or to the
// step under the pointer.
"use strict";

const TIMELINE_COLORS = {
  agent: "rgba(52,211,153,0.35)", person: "#f59e0b", fallback: "#ef4444", expert: "#a78bfa",
  gate: "#e2e8f0", violation: "#ef4444", collision: "#ef4444", end: "#7d8b9c", coach: "#34d399",
};

class Timeline {
  constructor(canvas, onSeek) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.onSeek = onSeek;
    this.length = 0;
    this.events = [];
    this.lane = [];
    this.cursor = null;
    this.hits = []; // [{x, t, kind}] of the markers drawn (tests read them)
    canvas.addEventListener("click", (e) => this._click(e));
  }

  set(series, events) {
    this.length = series.t.length;
    this.lane = series.t.map((_, i) => (series.takeover[i] ? series.actor[i] : "agent"));
    this.events = events || [];
    this.draw();
  }

  _x(t, width) { return this.length > 1 ? 6 + (t / (this.length - 1)) * (width - 12) : 6; }

  draw() {
    const canvas = this.canvas, ctx = this.ctx;
    const ratio = window.devicePixelRatio || 1;
    const width = canvas.clientWidth, height = canvas.clientHeight;
    if (!width || !height) return;
    canvas.width = Math.round(width * ratio); canvas.height = Math.round(height * ratio);
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    ctx.clearRect(0, 0, width, height);
    const laneTop = height - 12, step = this.length > 1 ? (width - 12) / (this.length - 1) : width;
    for (let i = 0; i < this.lane.length; i++) {
      ctx.fillStyle = TIMELINE_COLORS[this.lane[i]] || TIMELINE_COLORS.expert;
      ctx.fillRect(this._x(i, width) - step / 2, laneTop, Math.max(1, step), 8);
    }
    this.hits = [];
    for (const e of this.events) {
      const x = this._x(e.t, width);
      ctx.strokeStyle = ctx.fillStyle = TIMELINE_COLORS[e.kind] || TIMELINE_COLORS[e.actor] || "#e2e8f0";
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      if (e.kind === "gate") { ctx.moveTo(x, 2); ctx.lineTo(x - 4, 9); ctx.lineTo(x + 4, 9); ctx.closePath(); ctx.fill(); }
      else if (e.kind === "takeover_start" || e.kind === "takeover_end") {
        ctx.strokeStyle = TIMELINE_COLORS[e.actor] || TIMELINE_COLORS.expert;
        ctx.setLineDash(e.kind === "takeover_end" ? [2, 2] : []);
        ctx.moveTo(x, 11); ctx.lineTo(x, laneTop - 1); ctx.stroke(); ctx.setLineDash([]);
      } else if (e.kind === "coach_start" || e.kind === "coach_end") { // the agent drove, a person's label recorded
        ctx.strokeStyle = TIMELINE_COLORS.coach;
        ctx.setLineDash(e.kind === "coach_end" ? [2, 2] : [1, 3]);
        ctx.moveTo(x, laneTop - 10); ctx.lineTo(x, laneTop - 1); ctx.stroke(); ctx.setLineDash([]);
      } else if (e.kind === "violation" || e.kind === "collision") {
        ctx.moveTo(x - 4, 12); ctx.lineTo(x + 4, 20); ctx.moveTo(x + 4, 12); ctx.lineTo(x - 4, 20); ctx.stroke();
      } else if (e.kind === "end") { ctx.fillRect(x - 1, 2, 2, laneTop - 2); }
      else if (e.kind === "version") {
        ctx.fillStyle = "#2dd4bf"; ctx.font = "13px system-ui"; ctx.fillText(`v${e.version}`, x + 2, laneTop - 3);
      }
      this.hits.push({ x, t: e.t, kind: e.kind });
    }
    if (this.cursor !== null) {
      const x = this._x(this.cursor, width);
      ctx.strokeStyle = "#2dd4bf"; ctx.lineWidth = 1; ctx.beginPath(); ctx.moveTo(x, 0); ctx.lineTo(x, height); ctx.stroke();
    }
  }

  setCursor(t) { this.cursor = t; this.draw(); }

  // the nearest marker within 6 px, else the step under the pointer
  _click(event) {
    const rect = this.canvas.getBoundingClientRect();
    const x = event.clientX - rect.left;
    let best = null;
    for (const h of this.hits) if (Math.abs(h.x - x) <= 6 && (!best || Math.abs(h.x - x) < Math.abs(best.x - x))) best = h;
    const width = this.canvas.clientWidth;
    const t = best ? best.t : Math.round(((x - 6) / Math.max(1, width - 12)) * (this.length - 1));
    if (this.length) this.onSeek(Math.max(0, Math.min(this.length - 1, t)));
  }
}
window.Timeline = Timeline;

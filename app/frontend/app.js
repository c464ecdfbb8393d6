// The SAGE dashboard page: live stream, charts, operator input (keyboard and gamepad), replay, fine-tuning.
// The scene itself is viser's viewer in the iframe, on this same origin, so keys pressed inside the
// 3D view are caught here (capture phase) before viser's camera controls see them.
"use strict";

const HEARTBEAT_MS = 50; // operator input is re-sent this often while the page is focused
const WINDOW = 300; // live chart points (30 s at 10 Hz)
const DEADZONE = 0.15;
const RAMP_UP = 2.5; // keyboard axis change per second towards a pressed key
const RAMP_BACK = 4.0; // ... and back to zero when released

const S = {
  connected: false, role: "viewer", token: null, clientId: null,
  state: null, options: null, steps: 0, lastStep: null, k: 0,
  session: null, lastEpisode: -1, lastT: -1,
  live: [], replay: null, replayT: 0, errors: [], acks: 0,
  input: { throttle: 0, steer: 0, held: false, source: "keyboard", seq: 0 },
  inputsSent: 0, presence: { focused: true, visible: true },
  finetune: null, version: null,
};
window.sage = S; // for tests and for the curious

const $ = (id) => document.getElementById(id);
const fmt = (v, d = 3) => (v === null || v === undefined || !Number.isFinite(v) ? "–" : Number(v).toFixed(d));
const pct = (v) => (Number.isFinite(v) ? `${(100 * v).toFixed(1)}%` : "–");

// ---------------------------------------------------------------- charts
const css = getComputedStyle(document.documentElement);
const color = (name) => css.getPropertyValue(name).trim();
const bandColors = { person: "rgba(245,158,11,0.20)", fallback: "rgba(239,68,68,0.24)", expert: "rgba(167,139,250,0.20)" };
const fearChart = new StripChart($("chart-fear"), {
  title: "Fear vs threshold",
  series: [
    { key: "fear", label: "fear F", color: color("--fear"), width: 2, fill: true },
    { key: "threshold", label: "threshold τ", color: color("--threshold"), width: 1.4, dash: [6, 4] },
  ],
  yMin: 0, bandColors,
  // SUMO's first half-minute has no car near: fear is measured every step and lies near zero, which reads as a dead
  // chart unless it says so
  note: (chart) => {
    const fear = (chart.values.fear || []).filter(Number.isFinite);
    const tau = (chart.values.threshold || []).filter(Number.isFinite);
    if (fear.length < 10 || !tau.length) return null;
    const meanTau = tau.reduce((a, b) => a + b, 0) / tau.length;
    return Math.max(...fear) < 0.05 * meanTau ? "fear near zero: nothing close enough to matter yet (? explains)" : null;
  },
});
const curiosityChart = new StripChart($("chart-curiosity"), {
  title: "Curiosity",
  series: [{ key: "curiosity", label: "curiosity C", color: color("--curiosity"), width: 1.8, fill: true }],
  yMin: 0, bandColors,
});
fearChart.window = WINDOW;
curiosityChart.window = WINDOW;
S.charts = { fear: fearChart, curiosity: curiosityChart };
const horizonChart = new HorizonChart($("horizon")); // the imagined horizon, in the scene's HUD
S.horizonChart = horizonChart;

function pushLive(point) {
  S.live.push(point);
  if (S.live.length > WINDOW) S.live.splice(0, S.live.length - WINDOW);
  if (S.replay) return;
  const actor = point.takeover ? point.actor : null;
  fearChart.push(point.k, point, actor, point.boundary, WINDOW);
  curiosityChart.push(point.k, point, actor, point.boundary, WINDOW);
}

function redrawLive() {
  for (const chart of [fearChart, curiosityChart]) {
    chart.clear();
    chart.window = WINDOW;
    for (const p of S.live) chart.push(p.k, p, p.takeover ? p.actor : null, p.boundary, WINDOW);
  }
}

// ---------------------------------------------------------------- connection
let ws = null;
function send(message) {
  if (ws && ws.readyState === WebSocket.OPEN) { ws.send(JSON.stringify(message)); return true; }
  return false;
}
function sendOperator(message) {
  if (S.role !== "operator" || !S.token) { toast("This page is watching: take control first."); return false; }
  return send({ ...message, token: S.token });
}

function connect() {
  ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  ws.onopen = () => {
    S.connected = true; renderConnection(); send({ type: "claim" });
    // back after a lost connection (a server restart): viser's viewer does not reconnect by itself, so the
    // 3D view would freeze on its last frame; reload it so the operator never drives blind
    if (S.lostConnection) { S.lostConnection = false; reloadFrame(); }
  };
  ws.onclose = () => {
    if (S.connected) S.lostConnection = true;
    S.connected = false; S.role = "viewer"; S.token = null; renderConnection(); renderRole();
    setTimeout(connect, 1000);
  };
  ws.onmessage = (event) => {
    let msg;
    try { msg = JSON.parse(event.data); } catch { return; }
    const handler = handlers[msg.type];
    if (handler) handler(msg);
  };
}

const handlers = {
  welcome(msg) {
    S.clientId = msg.client;
    S.options = msg.options;
    applyState(msg.state);
    for (const step of msg.history || []) onStep(step);
    refreshSessions();
  },
  state(msg) { applyState(msg); },
  step(msg) { onStep(msg); },
  episode(msg) {
    const natural = ["terminated", "truncated", "ended"].includes(msg.reason);
    const outcome = msg.collision ? "collision" : msg.success ? "success" : msg.error ? "error"
      : natural || !msg.reason ? "done" : `ended: ${msg.reason}`;
    // a collision is an alert the operator must see, not a routine notice
    toast(`Episode ${msg.episode} ${outcome}: ${msg.steps} steps, takeover ${pct(msg.takeover_rate)}`,
      msg.collision ? "alert" : msg.error ? "error" : "info");
    if (S.finetune && msg.session === S.session) {
      S.finetune.episodes.push({ episode: msg.episode, version: msg.version, takeover_rate: msg.takeover_rate,
        steps: msg.steps, collision: Boolean(msg.collision), success: Boolean(msg.success) });
      drawTakeoverChart();
    }
    sessionsStale = true;
    setTimeout(() => { if (sessionsStale) refreshSessions(); }, 700);
  },
  control(msg) {
    S.role = msg.granted ? "operator" : "viewer";
    S.token = msg.granted ? msg.token : null;
    renderRole();
    if (msg.granted) sendPresence(true);
  },
  error(msg) {
    S.errors.push(msg);
    if (msg.op === "claim") { S.role = "viewer"; renderRole(); return; }
    toast(msg.error);
  },
  ack(msg) { S.acks += 1; },
  finetune(msg) { applyFinetune(msg); },
  replay(msg) { enterReplay(msg); },
  replay_frame(msg) { showReplayFrame(msg.t, msg.length, msg.labels, msg.scene); },
  replay_closed() { exitReplay(); },
  pong() {},
};

S.receive = (msg) => { const handler = handlers[msg.type]; if (handler) handler(msg); }; // tests feed messages here

// ---------------------------------------------------------------- state and steps
function applyState(state) {
  S.state = state;
  if (state.session !== S.session) {
    S.session = state.session; S.live = []; S.k = 0; S.lastEpisode = -1; S.lastT = -1; S.versionPicked = undefined;
    if (!S.replay) redrawLive();
  }
  const c = state.config;
  if (c.sim !== S.rateSim) { S.rateSim = c.sim; stepTimes.length = 0; renderRate(); } // a new simulator's rate starts afresh
  $("run-summary").textContent =
    `${c.sim} · scenario ${c.scenario ?? "–"} · ${state.policy_label} · expert: ${c.expert_mode.replace("_", " + ")}`;
  $("session-id").textContent = state.session || "not recording";
  const noGate = !state.has_gate;
  fearChart.emptyText = noGate ? "this policy has no gate: no fear or threshold" : "";
  curiosityChart.emptyText = noGate ? "no gate: no curiosity" : "";
  fearChart.dirty = curiosityChart.dirty = true;
  renderMode();
  renderControls();
  renderCounters(state.counters);
  S.version = state.version;
  applyFinetune(state.finetune);
  if (state.error && state.error !== S.lastShownError) { S.lastShownError = state.error; toast(state.error); }
}

function onStep(msg) {
  if (msg.session !== S.session && S.state) {
    S.session = msg.session; S.live = []; S.lastEpisode = -1; S.lastT = -1; redrawLive();
  }
  if (msg.episode < S.lastEpisode || (msg.episode === S.lastEpisode && msg.t <= S.lastT)) return; // already seen
  const boundary = msg.episode !== S.lastEpisode && S.lastEpisode >= 0;
  S.lastEpisode = msg.episode; S.lastT = msg.t;
  S.steps += 1; S.k += 1; S.lastStep = msg;
  stepTimes.push({ at: performance.now(), applied: msg.applied_ms });
  if (stepTimes.length > 40) stepTimes.shift();
  pushLive({
    k: S.k, episode: msg.episode, t: msg.t, fear: msg.fear, threshold: msg.threshold,
    curiosity: msg.curiosity, takeover: msg.takeover, actor: msg.actor, boundary,
  });
  if (!S.replay) renderStep(msg);
  else if (S.role === "operator" && msg.operator_held) {
    // the operator is driving the live run: never leave them looking at the past
    send({ type: "replay_close" }); exitReplay(); renderStep(msg);
    toast("You are driving: back to the live view.");
  } else if (S.role === "operator" && msg.request_person && !S.replayAsked) {
    S.replayAsked = true; // once per replay: the scripted fallback drives until the operator comes back
    toast("The gate asks for you on the live run: press Back to live.");
  }
  renderCounters(msg.counters);
}

const stepTimes = [];
function renderRate() {
  // the loop's own step times (not arrival times: a late page receives its history in one burst)
  const n = stepTimes.length;
  const span = n > 2 ? stepTimes[n - 1].applied - stepTimes[0].applied : 0;
  const rate = span > 0 ? (1000 * (n - 1)) / span : 0;
  const stale = n && performance.now() - stepTimes[n - 1].at > 1500;
  $("pill-rate").textContent = `${stale ? "0.0" : rate.toFixed(1)} Hz`;
}
setInterval(renderRate, 500);

function setBar(el, v) {
  v = Math.max(-1, Math.min(1, Number(v) || 0));
  el.style.setProperty("--l", `${50 + Math.min(v, 0) * 50}%`);
  el.style.setProperty("--w", `${Math.abs(v) * 50}%`);
}
function setPair(id, action, colorVar) {
  const bars = $(id).querySelectorAll("i");
  bars.forEach((bar, i) => { setBar(bar, action ? action[i] : 0); bar.style.setProperty("--c", colorVar); });
}

let lastBeep = 0;
function renderStep(msg) {
  $("hud-episode").textContent = msg.episode;
  $("hud-t").textContent = msg.t;
  $("hud-return").textContent = fmt(msg.counters ? msg.counters.episode_return : null, 2);
  renderLabels(msg.labels);
  const chip = $("actor-chip");
  chip.dataset.actor = msg.actor;
  chip.textContent = { agent: "AGENT", person: "PERSON", fallback: "FALLBACK", expert: "SCRIPTED EXPERT" }[msg.actor] || msg.actor;
  setPair("bar-arl", msg.a_rl, "var(--agent)");
  setPair("bar-act", msg.action, `var(--${msg.actor === "agent" ? "agent" : msg.actor})`);
  horizonChart.draw(msg.horizon);

  const banner = $("banner");
  const wrap = $("scene-wrap");
  const asked = msg.request_person && !msg.operator_held;
  wrap.classList.toggle("alert", Boolean(asked));
  if (asked) {
    banner.hidden = false; banner.dataset.kind = "alert";
    banner.textContent = S.role === "operator" ? "⚠ Gate fired: take over now (hold Space)" : "⚠ Gate fired: operator asked to take over";
    if (S.role === "operator" && $("sound").checked && performance.now() - lastBeep > 900) { beep(); lastBeep = performance.now(); }
  } else if (msg.takeover) {
    banner.hidden = false; banner.dataset.kind = msg.actor;
    const who = {
      person: "Person in control", fallback: "Scripted fallback in control (nobody holding on)",
      expert: "Scripted expert in control",
    }[msg.actor] || `${msg.actor} in control`;
    // why the scripted expert still has the wheel (the gate's reason, or past its hold a manoeuvre to finish)
    const why = msg.actor === "expert" || msg.actor === "fallback" ? TAKEOVER_WHY[msg.takeover_cause] : null;
    banner.textContent = why ? `${who}: ${why}` : who;
  } else {
    banner.hidden = true;
  }
}

const TAKEOVER_WHY = {
  fear: "fear over the threshold",
  hold: "holding on after the warning",
  hysteresis: "fear not yet under the release level",
  manoeuvre: "finishing its manoeuvre",
};

let labelKeys = "";
function renderLabels(labels) {
  const box = $("hud-labels");
  const entries = Object.entries(labels || {}).slice(0, 6);
  const keys = entries.map(([k]) => k).join("|");
  if (keys !== labelKeys) { // rebuild rows only when the simulator's label set changes
    box.innerHTML = "";
    for (const [k] of entries) {
      const name = document.createElement("span"); name.textContent = k.replace(/_/g, " ");
      const value = document.createElement("b"); value.dataset.key = k;
      box.append(name, value);
    }
    labelKeys = keys;
  }
  for (const [k, v] of entries) box.querySelector(`b[data-key="${CSS.escape(k)}"]`).textContent = String(v);
}

function renderCounters(c) {
  if (!c) return;
  $("st-rate").textContent = pct(c.takeover_rate);
  $("st-rate-ep").textContent = `episode ${pct(c.episode_takeover_rate)}`;
  $("st-collisions").textContent = c.collisions;
  $("st-violations").textContent = `violations ${c.violations}`;
  $("st-episodes").textContent = c.episodes;
  $("st-steps").textContent = `${c.steps} steps`;
  $("st-events").textContent = c.takeover_events;
  $("st-person").textContent = `person ${c.person_steps} · fallback ${c.fallback_steps}` +
    (c.coached_steps ? ` · coached ${c.coached_steps}` : "");
  const why = c.expert_share_by_cause || {};
  $("st-why").textContent = "scripted expert drove: " + (Object.values(why).some((v) => v > 0)
    ? `fear ${pct(why.fear)} · hold ${pct(why.hold)} · hysteresis ${pct(why.hysteresis)} · manoeuvre ${pct(why.manoeuvre)}`
    : "–");
  // how long the person took to take hold after the gate asked, and the largest action jump at a handover
  const latency = Number.isFinite(c.handover_latency_last) ? `answered in ${Math.round(1000 * c.handover_latency_last)} ms` : "";
  const jump = Number.isFinite(c.handover_jump_max) ? `max handover jump ${Math.round(100 * c.handover_jump_max)}%` : "";
  $("st-person").title = [latency, jump].filter(Boolean).join(" · ") || "no handover yet";
  if (latency) $("st-person").textContent += ` · ${latency}`;
}

function renderConnection() {
  const pill = $("pill-conn");
  pill.dataset.kind = S.connected ? "up" : "down";
  pill.textContent = S.connected ? "connected" : "offline";
}

function renderRole() {
  const pill = $("pill-role");
  const operator = S.role === "operator";
  pill.dataset.kind = operator ? "operator" : "viewer";
  pill.textContent = operator ? "OPERATOR" : "VIEWER";
  $("btn-claim").hidden = operator || !S.connected || Boolean(S.state && S.state.operator);
  renderControls();
  renderFinetune();
}

function renderMode() {
  const st = S.state;
  const pill = $("pill-mode");
  const kind = S.replay ? "replay" : st && st.paused ? "paused" : "live";
  pill.dataset.kind = kind;
  $("mode-text").textContent = kind.toUpperCase();
  $("btn-pause").textContent = st && st.paused ? "Resume" : "Pause";
  $("btn-claim").hidden = S.role === "operator" || !S.connected || Boolean(st && st.operator);
}

// ---------------------------------------------------------------- run controls
function fillSelect(select, items, value) {
  const current = JSON.stringify(items.map((i) => [i.value, i.label, i.disabled]));
  if (select.dataset.items !== current) {
    select.innerHTML = "";
    for (const item of items) {
      const option = document.createElement("option");
      option.value = item.value; option.textContent = item.label; option.disabled = Boolean(item.disabled);
      select.appendChild(option);
    }
    select.dataset.items = current;
  }
  select.value = value;
}

function renderControls() {
  const st = S.state;
  const opts = S.options;
  if (!st || !opts) return;
  const c = st.config;
  fillSelect($("sel-sim"), opts.sims.map((s) => ({ value: s.name, label: s.available ? s.name : `${s.name} (not available)`, disabled: !s.available })), c.sim);
  const sim = opts.sims.find((s) => s.name === c.sim);
  let scenarios = (sim && sim.scenarios.length ? sim.scenarios : []).map((s) => ({ value: String(s.id), label: String(s.label) }));
  if (!scenarios.some((s) => s.value === String(c.scenario))) scenarios.unshift({ value: String(c.scenario), label: String(c.scenario ?? "default") });
  fillSelect($("sel-scenario"), scenarios, String(c.scenario));
  let policies = ((opts.policies || {})[c.sim] || []).map((p) => ({ value: p.id, label: p.label }));
  if (!policies.some((p) => p.value === c.policy)) policies.unshift({ value: c.policy, label: st.policy_label || c.policy });
  fillSelect($("sel-policy"), policies, c.policy);
  for (const button of $("seg-expert").querySelectorAll("button")) button.classList.toggle("on", button.dataset.mode === c.expert_mode);
  if (document.activeElement !== $("speed")) $("speed").value = st.speed;
  $("speed-text").textContent = `${Number(st.speed).toFixed(2).replace(/0$/, "")}×`;
  const viewer = S.role !== "operator";
  for (const id of ["sel-sim", "sel-scenario", "sel-policy", "btn-pause", "btn-step", "btn-new", "speed"]) $(id).disabled = viewer;
  for (const button of $("seg-expert").querySelectorAll("button")) button.disabled = viewer;
}

function configure(fields) { sendOperator({ type: "configure", ...fields }); }
$("sel-sim").onchange = (e) => { configure({ sim: e.target.value }); e.target.blur(); };
$("sel-scenario").onchange = (e) => { configure({ scenario: e.target.value }); e.target.blur(); };
$("sel-policy").onchange = (e) => { configure({ policy: e.target.value }); e.target.blur(); };
for (const button of $("seg-expert").querySelectorAll("button")) {
  button.onclick = () => { configure({ expert_mode: button.dataset.mode }); button.blur(); };
}
$("btn-pause").onclick = (e) => { sendOperator({ type: "control", op: S.state && S.state.paused ? "resume" : "pause" }); e.target.blur(); };
$("btn-step").onclick = (e) => { sendOperator({ type: "control", op: "step" }); e.target.blur(); };
$("btn-new").onclick = (e) => { sendOperator({ type: "control", op: "new_episode" }); e.target.blur(); };
$("btn-claim").onclick = (e) => { send({ type: "claim" }); e.target.blur(); };
let speedTimer = null;
$("speed").oninput = (e) => {
  $("speed-text").textContent = `${Number(e.target.value).toFixed(2).replace(/0$/, "")}×`;
  clearTimeout(speedTimer);
  speedTimer = setTimeout(() => sendOperator({ type: "speed", value: Number(e.target.value) }), 120);
};
$("speed").onchange = (e) => e.target.blur();

// ---------------------------------------------------------------- sessions and replay
let sessionsStale = true;
async function refreshSessions() {
  sessionsStale = false;
  try {
    const sessions = await (await fetch("/api/sessions")).json();
    const select = $("sel-session");
    const keep = select.value || S.session;
    fillSelect(select, sessions.map((s) => ({ value: s.id, label: `${s.id} · ${s.episodes} ep` })), keep);
    if (!select.value && sessions.length) select.value = sessions[0].id;
    await refreshEpisodes();
  } catch (err) { /* the next refresh will tell */ }
}
// an episode that ended for another reason than the simulator's own end says why (a switch, a stop...)
function endNote(e) {
  const natural = !e.end_reason || ["terminated", "truncated", "ended"].includes(e.end_reason);
  return natural ? "" : ` · ended: ${e.end_reason}`;
}
async function refreshEpisodes() {
  const sid = $("sel-session").value;
  if (!sid) return;
  const response = await fetch(`/api/sessions/${encodeURIComponent(sid)}/episodes`);
  if (!response.ok) return;
  const episodes = await response.json();
  const select = $("sel-episode");
  const keep = select.value;
  fillSelect(select, episodes.map((e) => ({
    value: String(e.episode),
    label: `ep ${e.episode} · ${e.steps} steps · ${pct(e.takeover_rate)} takeover${e.metrics && e.metrics.collision ? " · collision" : ""}${e.finished ? endNote(e) : " · running"}`,
  })), keep);
  if (!select.value && episodes.length) select.value = String(episodes[episodes.length - 1].episode);
  updateDownloads();
}
function updateDownloads() {
  const sid = encodeURIComponent($("sel-session").value || "");
  const ep = $("sel-episode").value;
  const q = ep === "" ? "" : `?episode=${ep}`;
  $("dl-csv").href = `/api/sessions/${sid}/export.csv${q}`;
  $("dl-parquet").href = `/api/sessions/${sid}/export.parquet${q}`;
}
$("sel-session").onchange = (e) => { refreshEpisodes(); e.target.blur(); };
$("sel-episode").onchange = (e) => { updateDownloads(); e.target.blur(); };
$("btn-refresh").onclick = (e) => { refreshSessions(); e.target.blur(); };
$("sel-session").onfocus = () => { if (sessionsStale) refreshSessions(); };
$("sel-episode").onfocus = () => refreshEpisodes();
$("btn-replay").onclick = (e) => {
  e.target.blur();
  const session = $("sel-session").value;
  const episode = Number($("sel-episode").value);
  if (!session || !Number.isFinite(episode)) { toast("Pick a recorded session and episode first."); return; }
  send({ type: "replay_open", session, episode }); // any page may replay: it changes only this page's view
};
const replayView = new ReplayView($("replay-view"));
S.replayView = replayView;
const timeline = new Timeline($("timeline"), (t) => seek(t));

S.timeline = timeline;

function enterReplay(msg) {
  const series = msg.series;
  S.replay = { session: msg.session, episode: msg.episode, series, length: series.t.length, trail: msg.trail || [] };
  replayView.setStatic(msg.static);
  $("replay-view").hidden = false;
  $("timeline").hidden = false;
  timeline.set(series, msg.events);
  const actors = series.t.map((_, i) => (series.takeover[i] ? series.actor[i] : null));
  for (const chart of [fearChart, curiosityChart]) { chart.window = null; chart.setAll(series.t, series, actors); }
  $("replay-bar").hidden = false;
  $("replay-scrub").max = String(series.t.length - 1);
  renderMode();
}
function showReplayFrame(t, length, labels, scene) {
  if (!S.replay) return;
  S.replayT = t;
  replayView.draw(scene, S.replay.trail.slice(0, t + 1).filter(Boolean));
  const s = S.replay.series;
  fearChart.setCursor(s.t[t]); curiosityChart.setCursor(s.t[t]); timeline.setCursor(t);
  if (document.activeElement !== $("replay-scrub")) $("replay-scrub").value = String(t);
  $("replay-pos").textContent = `${t} / ${length - 1}`;
  renderStep({
    episode: S.replay.episode, t: s.t[t], actor: s.actor[t], takeover: s.takeover[t], a_rl: s.a_rl[t], action: s.action[t],
    horizon: s.horizon ? s.horizon[t] : null,
    request_person: false, labels,
    counters: { episode_return: s.reward.slice(0, t + 1).reduce((a, b) => a + (b || 0), 0) },
  });
  $("banner").hidden = false; $("banner").dataset.kind = "replay";
  $("banner").textContent = `Replay · ${S.replay.session} · episode ${S.replay.episode}`;
}
function exitReplay() {
  S.replay = null;
  S.replayAsked = false;
  $("replay-view").hidden = true;
  $("timeline").hidden = true;
  stopReplayPlayback();
  $("replay-bar").hidden = true;
  $("banner").hidden = true;
  fearChart.setCursor(null); curiosityChart.setCursor(null);
  redrawLive();
  renderMode();
}
let seekTimer = null;
let seekPending = null;
function seek(t) {
  seekPending = t;
  if (seekTimer) return;
  send({ type: "replay_seek", t });
  seekPending = null;
  seekTimer = setTimeout(() => { seekTimer = null; if (seekPending !== null) seek(seekPending); }, 60);
}
$("replay-scrub").oninput = (e) => seek(Number(e.target.value));
$("replay-scrub").onchange = (e) => e.target.blur();
$("replay-exit").onclick = (e) => { send({ type: "replay_close" }); e.target.blur(); };
let playTimer = null;
function stopReplayPlayback() { clearInterval(playTimer); playTimer = null; $("replay-play").textContent = "▶"; }
$("replay-play").onclick = (e) => {
  e.target.blur();
  if (playTimer) { stopReplayPlayback(); return; }
  $("replay-play").textContent = "❚❚";
  playTimer = setInterval(() => {
    if (!S.replay || S.replayT >= S.replay.length - 1) { stopReplayPlayback(); return; }
    seek(S.replayT + 1);
  }, 100);
};

// ---------------------------------------------------------------- fine-tuning
// A worker process fine-tunes the policy on this session and publishes versions; the loop takes a new one at
// the next episode boundary. The chart shows each episode's takeover rate, coloured by the version that drove it.
const vname = (n) => (n === null || n === undefined ? "–" : `v${String(n).padStart(4, "0")}`);
const versionColor = (n) => `hsl(${(170 + 47 * (n || 0)) % 360}, 70%, 58%)`;

function applyFinetune(ft) {
  S.finetune = ft || null;
  renderFinetune();
}

function renderFinetune() {
  const ft = S.finetune;
  const viewer = S.role !== "operator";
  for (const id of ["btn-pin", "btn-rollback", "btn-follow", "sel-version"]) $(id).disabled = viewer || !ft;
  if (!ft) {
    $("ft-worker").textContent = "off";
    $("ft-version").textContent = "–";
    $("ft-mode").textContent = "runs for a trained policy on a recorded session";
    $("ft-phase").textContent = "–";
    $("ft-losses").textContent = "";
    $("ft-bar").style.setProperty("--p", "0%");
    fillSelect($("sel-version"), [], "");
    drawTakeoverChart();
    return;
  }
  const worker = ft.alive ? `worker pid ${ft.pid}` : ft.restart_in !== null ? `restarting in ${ft.restart_in.toFixed(0)} s` : "worker down";
  $("ft-worker").textContent = worker + (ft.restarts ? ` · ${ft.restarts} restart${ft.restarts > 1 ? "s" : ""}` : "");
  $("ft-version").textContent = vname(ft.in_control);
  let mode = ft.pinned !== null ? `pinned to ${vname(ft.pinned)}` : "following the newest promoted version";
  if (ft.pending !== null) mode += ` · ${vname(ft.pending)} from the next episode`;
  // a version drives only once its headless evaluation found it no worse than the one in control
  const newest = ft.versions.length ? ft.versions[ft.versions.length - 1] : null;
  const verdict = newest && newest.number > 0 ? newest.promotion : null;
  if (ft.last_rollback) mode += ` · rolled back: ${ft.last_rollback}`;
  else if (newest && newest.number > 0 && !verdict) mode += ` · ${vname(newest.number)} is being evaluated`;
  else if (verdict && !verdict.promoted) mode += ` · ${vname(newest.number)} kept, not promoted: ${verdict.reason}`;
  $("ft-mode").textContent = mode;
  $("ft-mode").title = mode;
  const p = ft.progress || {};
  const share = p.updates ? (100 * p.update) / p.updates : 0;
  $("ft-bar").style.setProperty("--p", `${ft.phase === "training" ? share : ft.phase === "round done" ? 100 : 0}%`);
  $("ft-phase").textContent = ft.phase === "training" ? `training ${p.update}/${p.updates}` : ft.phase;
  const l = ft.losses || {};
  const parts = [["critic", l.critic_loss], ["actor", l.actor_loss], ["imitation", l.bc_loss], ["ω", l.omega_mean]]
    .filter(([, v]) => Number.isFinite(v)).map(([k, v]) => `${k} ${fmt(v, 3)}`);
  $("ft-losses").textContent = parts.length ? parts.join(" · ") : "losses appear after the first round";
  $("ft-losses").title = ft.error || "";
  const select = $("sel-version");
  const keep = S.versionPicked !== undefined ? S.versionPicked : String(ft.in_control);
  const items = ft.versions.slice().reverse().map((v) => ({
    value: String(v.number),
    label: `${vname(v.number)}${v.parent !== null ? ` · from ${vname(v.parent)}` : " · deployed"}` +
      `${v.updates ? ` · ${v.updates} upd` : ""}${v.number === ft.in_control ? " · in control" : ""}` +
      `${promotionTag(v)}`,
  }));
  fillSelect(select, items, items.some((i) => i.value === keep) ? keep : String(ft.in_control));
  drawTakeoverChart();
}

function promotionTag(v) {
  if (v.number === 0) return "";
  const p = v.promotion;
  if (!p) return " · evaluating";
  if (p.rolled_back) return " · rolled back";
  return p.promoted ? " · promoted" : " · not promoted";
}

function drawTakeoverChart() {
  const canvas = $("chart-takeover");
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (!w || !h) return;
  if (canvas.width !== Math.round(w * dpr)) { canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr); }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, w, h);
  ctx.font = "10px system-ui, sans-serif";
  const episodes = S.finetune ? S.finetune.episodes.slice(-60) : [];
  ctx.fillStyle = color("--muted");
  if (!episodes.length) {
    ctx.fillText(S.finetune ? "takeover rate per episode appears as episodes end" : "no fine-tuning", 8, h / 2 + 3);
    return;
  }
  const top = 12, bottom = h - 4, left = 26, slot = (w - left - 4) / Math.max(episodes.length, 12);
  ctx.strokeStyle = "#26323f"; ctx.lineWidth = 1;
  for (const frac of [0, 0.5, 1]) {
    const y = bottom - frac * (bottom - top);
    ctx.beginPath(); ctx.moveTo(left, y + 0.5); ctx.lineTo(w - 4, y + 0.5); ctx.stroke();
    ctx.fillText(`${Math.round(frac * 100)}%`, 2, y + 3);
  }
  let previous = null, labelledAt = -Infinity;
  episodes.forEach((e, i) => {
    const x = left + i * slot;
    const barH = Math.max(1, (bottom - top) * Math.min(1, e.takeover_rate || 0));
    ctx.fillStyle = versionColor(e.version);
    ctx.fillRect(x + 1, bottom - barH, Math.max(1, slot - 2), barH);
    if (e.collision) { ctx.fillStyle = "#ef4444"; ctx.fillRect(x + 1, top - 4, Math.max(2, slot - 2), 3); }
    if (e.version !== previous) {
      ctx.fillStyle = versionColor(e.version);
      ctx.fillRect(x, top, 1, bottom - top); // where a new version took over
      if (x - labelledAt > 24) { ctx.fillText(vname(e.version).replace(/^v0+(?=\d)/, "v"), x + 2, 9); labelledAt = x; }
      previous = e.version;
    }
  });
}
new ResizeObserver(() => drawTakeoverChart()).observe($("chart-takeover"));

function versionAction(op) {
  const number = Number($("sel-version").value);
  if (op !== "follow" && !Number.isFinite(number)) { toast("Pick a version first."); return; }
  sendOperator(op === "follow" ? { type: "version", op } : { type: "version", op, version: number });
}
$("btn-pin").onclick = (e) => { versionAction("pin"); e.target.blur(); };
$("btn-rollback").onclick = (e) => { versionAction("rollback"); e.target.blur(); };
$("btn-follow").onclick = (e) => { versionAction("follow"); e.target.blur(); };
$("sel-version").onchange = (e) => { S.versionPicked = e.target.value; e.target.blur(); };

// ---------------------------------------------------------------- operator input
const keys = new Set();
let sticky = false;
let coaching = false; // key C: your controls label the agent's own steps (recorded for fine-tuning, not executed)
const DRIVE = {
  KeyW: ["throttle", 1], ArrowUp: ["throttle", 1], KeyS: ["throttle", -1], ArrowDown: ["throttle", -1],
  KeyA: ["steer", 1], ArrowLeft: ["steer", 1], KeyD: ["steer", -1], ArrowRight: ["steer", -1],
};
const OURS = new Set(["Space", "KeyT", "KeyV", "KeyC", "Escape", ...Object.keys(DRIVE)]);

// Taking over must work wherever the focus is: these keys are always the operator's (the page has no
// text fields); pickers and sliders give the focus back as soon as they change.
function onKey(event, down) {
  if (event.key === "?") { if (down && !event.repeat) toggleHelp(); event.preventDefault(); return; }
  if (event.code === "Escape" && down && !$("help").hidden) toggleHelp(false);
  if (!OURS.has(event.code)) return;
  event.preventDefault();
  event.stopImmediatePropagation(); // viser's camera keys never see these
  if (down && event.repeat) return;
  if (S.role !== "operator") { if (down && event.code === "Space") toast("This page is watching: take control first."); return; }
  if (event.code === "KeyV") { if (down) toggleView(); return; }
  if (event.code === "KeyT") { if (down) sticky = !sticky; }
  else if (event.code === "KeyC") { if (down) { coaching = !coaching; toast(coaching ? "Coaching: steer along; the agent keeps driving, your controls are recorded as labels." : "Coaching off."); } }
  else if (event.code === "Escape") { if (down) { sticky = false; coaching = false; } }
  else if (down) keys.add(event.code);
  else keys.delete(event.code);
  tick(true);
}
// the 3D view follows the ego (default) or shows the whole area; one shared scene, so the operator's key
function toggleView() {
  const next = S.state && S.state.view === "overview" ? "follow" : "overview";
  sendOperator({ type: "view", mode: next });
}
function attachKeys(target) {
  if (!target || target.__sageKeys) return;
  target.__sageKeys = true;
  target.addEventListener("keydown", (e) => onKey(e, true), true);
  target.addEventListener("keyup", (e) => onKey(e, false), true);
  target.addEventListener("blur", () => setTimeout(checkPresence, 0), true);
  target.addEventListener("focus", () => setTimeout(checkPresence, 0), true);
}
attachKeys(window);
const frame = $("scene");

// Without a GPU (software WebGL) every frame of the 3D view is paid for on this page's main thread,
// delaying key handling and input heartbeats; render the view at a lower resolution then.
// ?sceneDpr=<ratio> forces a ratio (e.g. 1 for full-quality screenshots).
function softwareWebGL() {
  try {
    const gl = document.createElement("canvas").getContext("webgl");
    const info = gl && gl.getExtension("WEBGL_debug_renderer_info");
    const renderer = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)).toLowerCase() : "";
    return /swiftshader|llvmpipe|softpipe|software/.test(renderer);
  } catch (err) { return false; }
}
const sceneDpr = new URLSearchParams(location.search).get("sceneDpr") || (softwareWebGL() ? "0.6" : null);
S.sceneDpr = sceneDpr;
// viser's own control panel and its notifications (e.g. "software WebGL") are not part of this product
const FRAME_CSS = "[data-dock-group], .mantine-Notifications-root { display: none !important; }";
const attachFrame = () => {
  try {
    attachKeys(frame.contentWindow);
    const doc = frame.contentDocument;
    if (doc && doc.head && !doc.getElementById("sage-frame-css")) {
      const style = doc.createElement("style");
      style.id = "sage-frame-css"; style.textContent = FRAME_CSS;
      doc.head.appendChild(style);
    }
  } catch (err) { /* not same-origin: keys pressed inside the view then go to viser */ }
};
frame.addEventListener("load", attachFrame);
const frameUrl = () => `/viser/?darkMode${sceneDpr ? `&fixedDpr=${encodeURIComponent(sceneDpr)}` : ""}`;
function reloadFrame() {
  S.frameReloads = (S.frameReloads || 0) + 1;
  frame.src = `${frameUrl()}&reconnect=${S.frameReloads}`;
}
frame.src = frameUrl();

function deadzone(v) {
  const a = Math.abs(v);
  return a < DEADZONE ? 0 : (Math.sign(v) * (a - DEADZONE)) / (1 - DEADZONE);
}
function readGamepad() {
  const pads = navigator.getGamepads ? Array.from(navigator.getGamepads()).filter(Boolean) : [];
  for (const pad of pads) {
    const axes = pad.axes || [];
    const buttons = pad.buttons || [];
    const trigger = Math.max(...[6, 7].map((i) => (buttons[i] ? (buttons[i].value || (buttons[i].pressed ? 1 : 0)) : 0)));
    const steer = -deadzone(axes[0] || 0);
    const throttle = -deadzone(axes[1] || 0);
    if (trigger > 0.5 || steer !== 0 || throttle !== 0) return { trigger: trigger > 0.5, steer, throttle };
  }
  return null;
}

let lastTick = performance.now();
function ramp(value, target, dt) {
  const rate = target === 0 || Math.sign(target) !== Math.sign(value) ? RAMP_BACK : RAMP_UP;
  const delta = Math.max(-rate * dt, Math.min(rate * dt, target - value));
  return Math.max(-1, Math.min(1, value + delta));
}
function tick(immediate) {
  const now = performance.now();
  const dt = Math.min(0.2, (now - lastTick) / 1000);
  lastTick = now;
  const inp = S.input;
  const target = { throttle: 0, steer: 0 };
  for (const code of keys) if (DRIVE[code]) target[DRIVE[code][0]] += DRIVE[code][1];
  inp.throttle = ramp(inp.throttle, Math.max(-1, Math.min(1, target.throttle)), dt);
  inp.steer = ramp(inp.steer, Math.max(-1, Math.min(1, target.steer)), dt);
  const pad = readGamepad();
  inp.source = pad ? "gamepad" : "keyboard";
  if (pad && (pad.throttle !== 0 || pad.steer !== 0)) { inp.throttle = pad.throttle; inp.steer = pad.steer; }
  inp.held = keys.has("Space") || sticky || Boolean(pad && pad.trigger);
  renderInput();
  checkPresence();
  if (S.role === "operator" && S.presence.focused && S.presence.visible) {
    inp.seq += 1;
    if (send({ type: "input", token: S.token, seq: inp.seq, ts: performance.timeOrigin + performance.now(),
               held: inp.held, throttle: round(inp.throttle), steer: round(inp.steer), source: inp.source,
               coach: coaching })) S.inputsSent += 1;
  }
}
const round = (v) => Math.round(v * 1000) / 1000;
setInterval(() => tick(false), HEARTBEAT_MS);

function renderInput() {
  setBar($("m-throttle").querySelector("i"), S.input.throttle);
  setBar($("m-steer").querySelector("i"), S.input.steer);
  $("op-source").textContent = S.input.source + (sticky ? " · sticky" : "");
  const held = $("op-held");
  held.textContent = S.input.held ? "TAKING OVER" : coaching ? "COACHING" : "released";
  held.className = S.input.held ? "held-on" : coaching ? "coach-on" : "held-off";
}

function sendPresence(force) {
  if (S.role !== "operator") return;
  send({ type: "presence", token: S.token, focused: S.presence.focused, visible: S.presence.visible });
}
function checkPresence() {
  const focused = document.hasFocus();
  const visible = document.visibilityState === "visible";
  if (focused !== S.presence.focused || visible !== S.presence.visible) {
    S.presence = { focused, visible };
    if (!focused || !visible) { keys.clear(); } // keys released while away never send keyup
    sendPresence();
  }
}
document.addEventListener("visibilitychange", () => checkPresence());
window.addEventListener("pagehide", () => { if (ws) ws.close(); });

// ---------------------------------------------------------------- small things
let audio = null;
function beep() {
  try {
    audio = audio || new AudioContext();
    const osc = audio.createOscillator();
    const gain = audio.createGain();
    osc.frequency.value = 880; gain.gain.value = 0.08;
    osc.connect(gain).connect(audio.destination);
    osc.start(); osc.stop(audio.currentTime + 0.12);
  } catch (err) { /* no audio device */ }
}
let toastTimer = null;
// The help overlay explains the signals; `?` (anywhere, the 3D view included) or the ? pill opens it.
function toggleHelp(show = $("help").hidden) {
  $("help").hidden = !show;
}
$("btn-help").onclick = (e) => { toggleHelp(); e.currentTarget.blur(); };

function toast(text, kind = "error") {
  const el = $("toast");
  el.textContent = text; el.dataset.kind = kind; el.hidden = false;
  clearTimeout(toastTimer);
  toastTimer = setTimeout(() => { el.hidden = true; }, 4000);
}

renderConnection();
renderRole();
connect();

"""The paper's route-shift study on SUMO: phase C1 on route 1, then phase C2 on route 2 with special vehicles.

:class:`RouteShift` is a ``core.train`` episode hook: before each training episode it applies that episode's
scenario from :func:`sims.sumo.route_shift_schedule` (it takes effect at the env's next reset) and, at the
switch, hands the expert role to the C2 expert when one was given (the paper supervises each phase with an RL
policy trained on that route; by default SUMO's own driver model is the expert in both phases).

A run folder of this protocol holds ``study.json`` (``{"protocol": "route-shift", "c1": N, "c2": M, ...}``)
beside ``metrics.jsonl``, whose rows carry ``route`` and ``special_vehicles`` (the env's metrics), so the
schedule actually driven can be read back. :func:`studies.route_shift_figures.write_figures` draws the paper's
panels into the folder.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from core.experts import PolicyExpert
from core.loop import Expert, Runner
from studies.route_shift_schedule import DEFAULT_C1, DEFAULT_C2, RouteShiftEpisode

PROTOCOL = "route-shift"
STUDY_FILE = "study.json"


@dataclass
class RouteShift:
    """Apply the route-shift schedule episode by episode; swap the expert at the switch if a C2 expert is given."""

    c1: int = DEFAULT_C1
    c2: int = DEFAULT_C2
    expert_c2: Expert | None = None
    """The expert of phase C2 (None: keep the C1 expert, e.g. SUMO's driver model, in both phases)."""
    c1_steps: int | None = None
    """C1 takes exactly this many interaction steps (its last episode cut there: :meth:`episode_cap`), C2 the rest
    of the step budget (the studies' budgets are in steps); None: after ``c1`` episodes, and ``c2`` more end the
    run."""
    c1_share: float | None = None
    """Instead of ``c1_steps``: C1 takes this share of the interaction steps left after the demonstrations (the run's
    step budget, set when interaction starts)."""
    applied: list[dict[str, Any]] = field(default_factory=list)
    """The scenario applied before each episode, in order."""
    switch_episode: int | None = None
    """The first C2 episode, once it has started."""

    def __post_init__(self) -> None:
        from studies.route_shift_schedule import route_shift_schedule

        if self.c1_share is not None and not 0.0 < self.c1_share < 1.0:
            raise ValueError(f"the C1 share must be in (0, 1), got {self.c1_share}")

        self.schedule = route_shift_schedule(self.c1, self.c2)
        self.steps = 0

    @property
    def episodes(self) -> int | None:
        return None if self.by_steps else self.c1 + self.c2

    @property
    def by_steps(self) -> bool:
        return self.c1_steps is not None or self.c1_share is not None

    def start_interaction(self, steps_done: int, train_steps: int | None) -> None:
        """Called by the trainer after the demonstrations: a share of what is left of the budget becomes C1."""
        if self.c1_share is not None:
            if train_steps is None:
                raise ValueError("a C1 share of the budget needs a step budget (--train-steps)")
            self.c1_steps = max(1, round(self.c1_share * max(0, train_steps - steps_done)))

    def _entry(self, episode: int, runner: Runner) -> RouteShiftEpisode:
        if not self.by_steps:
            if episode >= len(self.schedule):
                raise ValueError(f"episode {episode} is past the route-shift schedule of {len(self.schedule)} episodes")
            return self.schedule[episode]
        if episode > 0:
            self.steps += runner.t  # the previous episode's steps (the runner resets t when it starts the next)
        assert self.c1_steps is not None, "start_interaction sets the C1 steps from the share"
        in_c2 = self.switch_episode is not None or self.steps >= self.c1_steps
        return RouteShiftEpisode(episode, "C2" if in_c2 else "C1", 2 if in_c2 else 1, in_c2)

    def __call__(self, episode: int, runner: Runner) -> None:
        entry = self._entry(episode, runner)
        kwargs = entry.env_kwargs()
        runner.set_next_reset_options(kwargs)  # gymnasium reset(options=...): the env checks the names
        if entry.phase == "C2" and self.switch_episode is None:
            self.switch_episode = episode
            if self.expert_c2 is not None and runner.expert is not None:
                runner.set_expert(self.expert_c2)  # only methods with takeovers have an expert to swap
        self.applied.append({"episode": episode, "phase": entry.phase, **kwargs})

    def episode_cap(self) -> int | None:
        """Steps left in C1 while the coming episode is in it (a budget in steps): C1's last episode is cut where
        C1's steps end, so that every method gets exactly the same steps in each phase, and C2 its share however
        long C1's episodes run."""
        if not self.by_steps or not self.applied or self.applied[-1]["phase"] != "C1":
            return None
        assert self.c1_steps is not None
        return max(1, self.c1_steps - self.steps)

    def describe(self, method: str, expert: str | None, expert_c2: str | None) -> dict[str, Any]:
        described: dict[str, Any] = {
            "protocol": PROTOCOL,
            "c1": None if self.by_steps else self.c1,
            "c2": None if self.by_steps else self.c2,
            "switch_episode": None if self.by_steps else self.c1,
            "method": method,
            "expert_c1": expert or "sumo",
            "expert_c2": expert_c2 or expert or "sumo",
        }
        if self.c1_steps is not None:
            described["c1_steps"] = self.c1_steps
        if self.c1_share is not None:
            described["c1_share"] = self.c1_share
        return described


def policy_expert(run: str | Path) -> PolicyExpert:
    """A run's deterministic policy as the expert of phase C2 (``--expert-c2``); it must fit the SUMO env."""
    from core.agents import load_agent
    from sims.sumo.env import OBS_SIZE

    agent = load_agent(run)
    if (agent.meta.obs_dim, agent.meta.act_dim) != (OBS_SIZE, 1):
        raise ValueError(
            f"--expert-c2 {run}: its policy takes {agent.meta.obs_dim} observations / {agent.meta.act_dim} actions, "
            f"the SUMO env has {OBS_SIZE} / 1"
        )
    return PolicyExpert(agent.policy)


def write_study(out: Path, description: dict[str, Any]) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / STUDY_FILE
    path.write_text(json.dumps(description, indent=2) + "\n")
    return path


@dataclass
class StudyRun:
    """A route-shift run folder as the figures need it."""

    path: Path
    label: str
    method: str
    rows: list[dict[str, Any]]
    """The training episodes' rows (demonstrations left out), in order."""
    switch: int
    """Index (0-based, in ``rows``) of the first C2 episode."""
    takes_over: bool = True
    """Whether the method hands control to an expert (its config's ``takeover``; a method without one, e.g. SAC,
    has no takeover share to speak of)."""


def read_run(path: str | Path, label: str | None = None) -> StudyRun:
    """Read a route-shift run folder (``metrics.jsonl`` + ``study.json``); a clear error when it is not one."""
    folder = Path(path)
    metrics = folder / "metrics.jsonl"
    if not metrics.is_file():
        raise FileNotFoundError(f"{folder} has no metrics.jsonl: not a run folder")
    rows = []
    for number, line in enumerate(metrics.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{metrics}:{number} is not JSON: {exc}") from None
        if row.get("phase", "train") == "train":
            rows.append(row)
    if not rows:
        raise ValueError(f"{metrics} holds no training episodes")
    study: dict[str, Any] = {}
    if (folder / STUDY_FILE).is_file():
        study = json.loads((folder / STUDY_FILE).read_text())
    switch = study.get("switch_episode")
    if switch is None:  # a run without study.json: the first episode on another route than the first one
        routes = [r.get("route") for r in rows]
        switch = next((i for i, route in enumerate(routes) if route != routes[0]), None)
        if switch is None and study.get("protocol") != PROTOCOL:
            raise ValueError(f"{folder} is not a route-shift run: no study.json and every episode on one route")
        if switch is None:  # a route-shift run (switch by steps) that ended before C2 began: every episode is C1
            switch = len(rows)
    agent: dict[str, Any] = {}
    if (folder / "config.json").is_file():
        agent = json.loads((folder / "config.json").read_text()).get("agent", {})
    method = study.get("method") or agent.get("method") or "?"
    takes_over = agent.get("takeover")
    if takes_over is None:  # no config: a run whose episodes were never taken over is taken as one without a gate
        takes_over = any(int(r.get("takeovers", 0)) > 0 for r in rows)
    return StudyRun(folder, label or method_label(method), method, rows, int(switch), bool(takes_over))


PHASE_COLUMNS = ("success", "collision", "red_light", "timeout", "takeover_rate", "mean_fear", "mean_curiosity")


def phase_rows(run: StudyRun, part: int = 3) -> dict[str, list[dict[str, Any]]]:
    """The episodes that tell the story: the end of C1 (stable?), the start of C2 (the drop) and the end of C2
    (recovered?), each a ``1/part`` share of its phase."""
    c1, c2 = run.rows[: run.switch], run.rows[run.switch :]
    k1, k2 = max(1, len(c1) // part), max(1, len(c2) // part)
    out: dict[str, list[dict[str, Any]]] = {}
    if c1:
        out[f"{run.label}: C1 last {k1}"] = c1[-k1:]
    if c2:
        out[f"{run.label}: C2 first {k2}"] = c2[:k2]
        out[f"{run.label}: C2 last {k2}"] = c2[-k2:]
    return out


def phase_table(runs: list[StudyRun], part: int = 3) -> str:
    """A plain-text table of :func:`phase_rows` for every run (rates as counts and percentages)."""
    from core.report import format_table

    named: dict[str, list[dict[str, Any]]] = {}
    for run in runs:
        named.update(phase_rows(run, part))
    return format_table(named, PHASE_COLUMNS)


SHIFT_KEYS = ("success", "collision", "red_light")
"""The per-episode outcomes averaged over each part of a phase in the study's table."""


def _share(rows: list[dict[str, Any]], key: str) -> float:
    """Mean of a 0/1 outcome over ``rows``; NaN when there are none (the table shows "–")."""
    return float(sum(float(r.get(key, 0.0)) for r in rows) / len(rows)) if rows else math.nan


def _takeover_share(rows: list[dict[str, Any]]) -> float:
    """The expert's share of the steps of ``rows`` (NaN when they hold none)."""
    steps = sum(int(r["steps"]) for r in rows)
    return sum(int(r.get("takeovers", 0)) for r in rows) / steps if steps else math.nan


def shift_metrics(run: StudyRun, part: int = 3) -> dict[str, float]:
    """The route-shift study's training metrics of one run (one method, one seed), for its table.

    ``c1_late_*``, ``c2_early_*``, ``c2_late_*``: success, collision and red-light shares of the last ``1/part`` of
    C1's episodes and of the first and last ``1/part`` of C2's (at least one episode each). ``c2_takeover_rate``:
    the expert's share of all of C2's steps. Over C2, read per seed so that the table's interval is that of a
    paired difference: ``c2_takeover_early`` / ``c2_takeover_late``, the expert's share of the steps of C2's first
    and last ``1/part`` of episodes, ``c2_takeover_change`` late minus early (negative: the takeover falls as the
    policy adapts), and ``c2_collision_change`` the same for collisions. NaN, shown as "–", where a metric does not
    apply: no C2 episodes; a change with fewer than two C2 episodes (its two ends would be the same episodes);
    takeover shares of a method that never hands over (``c2_takeover_rate`` stays 0 there, as measured)."""
    if part < 1:
        raise ValueError(f"part must be at least 1, got {part}")
    c1, c2 = run.rows[: run.switch], run.rows[run.switch :]
    c1_late = c1[-max(1, len(c1) // part) :] if c1 else []
    c2_early = c2[: max(1, len(c2) // part)] if c2 else []
    c2_late = c2[-max(1, len(c2) // part) :] if c2 else []
    result: dict[str, float] = {}
    for name, rows in (("c1_late", c1_late), ("c2_early", c2_early), ("c2_late", c2_late)):
        for key in SHIFT_KEYS:
            result[f"{name}_{key}"] = _share(rows, key)
    steps = sum(int(r["steps"]) for r in c2)
    result["c2_takeover_rate"] = sum(int(r.get("takeovers", 0)) for r in c2) / max(steps, 1)
    over_time = len(c2) >= 2
    early = _takeover_share(c2_early) if run.takes_over else math.nan
    late = _takeover_share(c2_late) if run.takes_over else math.nan
    result["c2_takeover_early"], result["c2_takeover_late"] = early, late
    result["c2_takeover_change"] = late - early if over_time else math.nan
    result["c2_collision_change"] = (
        result["c2_late_collision"] - result["c2_early_collision"] if over_time else math.nan
    )
    return result


def method_label(method: str) -> str:
    return {"sage": "SAGE-RL", "sac": "RL (SAC)", "fni-rl": "FNI-RL", "td3": "TD3", "hg-dagger": "HG-DAgger"}.get(
        method, method
    )

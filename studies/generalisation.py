"""Seen against unseen ground: does the gate's self-awareness transfer to a procedural family's test split?

For one simulator and one run, two grounds are measured the same way:

- **seen**: the scenarios the run was trained on (its ``RunConfig.scenarios``), episodes split evenly among them;
- **unseen**: a procedural family's test split (``ugv-fields:test``, :mod:`sims.ugv.fields`), which no world
  model, τ bound or operating point was fitted or chosen on.

On each, with the machinery of ``sage gate evaluate`` (:mod:`studies.calibrate`):

1. the policy drives with its SAGE gate and no expert (so danger plays out); every step is labelled "a violation
   within ``horizon_s``" (:func:`studies.calibrate.labels_within`), and fear's and curiosity's AUROC for that
   label, the gate's firing rate on those steps and elsewhere, and the mean curiosity and τ over the steps are
   recorded (curiosity as ``sage gate evaluate`` scores it: the value observed on arriving at the state);
2. the policy with its own gate and the scripted expert (:func:`studies.calibrate.run_gated`): the share of
   episodes with a violation, with its 95% Wilson interval, at the takeover rate.

``python -m studies.generalisation --sim ugv --episodes 60`` writes the table to ``docs/generalisation.md``; every
measured part is kept in a JSON cache beside it (``--cache``), so a run that stops resumes where it stopped. Grounds
measured by a command of their own into a committed file (:data:`EXTRA_GROUNDS`, e.g. the UGV test fields with two or
more movers) are subsections of their simulator's section, made from those files (``--extras-only`` puts them in
again, measuring nothing). Writing the project's document also refreshes the README's summary of it
(:mod:`studies.generalisation_summary`).
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from core.agents import load_agent
from core.device import processor_name
from core.loop import Runner, StepRecord
from core.metrics import auroc
from studies.calibrate import EVAL_SEED, labels_within, pool_points, run_gated, violation_interval
from studies.generalisation_summary import FRESH_TITLE, update_readme

FAMILIES: dict[str, str] = {
    "sumo": "sumo-shift",
    "ugv": "ugv-fields",
    "highway": "highway-shift",
    "pedestrian": "pedestrian-shift",
}
"""Each simulator's procedural family (its ``:train`` / ``:test`` names)."""
DEFAULT_OUT = Path("docs/generalisation.md")
FRESH_SEED = 11_000_000
"""The first episode seed of a fresh draw of every ground (``--first-seed``): a block no table, rule or choice has read,
so that a figure on it tests the choices made while reading the table's block (:data:`EVAL_SEED`) many times."""
CHUNK = 10
"""Episodes measured (and cached) together."""


@dataclass
class SignalPart:
    """What the gate's signals did on one scenario, the policy driving alone."""

    scenario: str
    episodes: int
    steps: int
    violations: int
    """Episodes with a violation."""
    fear: list[float]
    cost: list[float]
    """Fear's parts: the predicted violation probability ĉ ..."""
    sigma: list[float]
    """... and the normalised uncertainty σ̂ (the world model's epistemic term)."""
    curiosity: list[float]
    """Curiosity observed on arriving at each step's state (NaN at an episode's first step)."""
    tau: list[float]
    fired: list[bool]
    violation: list[bool]
    episode: list[int]


@dataclass
class GroundRow:
    """One ground's row of the table."""

    ground: str
    scenarios: list[str]
    episodes: int
    steps: int
    violations: int
    positives: int
    fear_auroc: float
    cost_auroc: float
    sigma_auroc: float
    curiosity_auroc: float
    fire_before_violation: float
    fire_elsewhere: float
    curiosity_mean: float
    tau_mean: float
    gate: dict[str, float] = field(default_factory=dict)
    """:func:`studies.calibrate.run_gated`'s point, pooled over the ground's scenarios (empty: not measured)."""
    parts: list[SignalPart] = field(default_factory=list, repr=False)
    """The signal chunks the row was made of."""

    @property
    def gate_violations(self) -> tuple[int, int]:
        episodes = int(self.gate.get("episodes", 0))
        return round(self.gate.get("violation_rate", math.nan) * episodes) if episodes else 0, episodes


def collect_signals(
    agent: Any,
    make_env: Callable[[], Any],
    scenario: str,
    episodes: int,
    max_steps: int | None,
    first_seed: int,
    gate_settings: Mapping[str, Any] | None = None,
) -> SignalPart:
    """The policy with its own gate (``gate_settings`` over it) and no expert over ``episodes`` (seeds
    ``first_seed + i``): every step's signals."""
    gate = agent.make_gate(**dict(gate_settings or {}))
    env = make_env()
    part = SignalPart(scenario, episodes, 0, 0, [], [], [], [], [], [], [], [])
    arriving = [math.nan]
    try:
        runner = Runner(env, agent.policy, gate, None, seed=first_seed, deterministic=True)

        def record(r: StepRecord) -> None:
            part.fear.append(float(r.fear))
            part.cost.append(float(gate.detail.cost))
            part.sigma.append(float(gate.detail.sigma))
            part.curiosity.append(arriving[0])
            part.tau.append(float(r.threshold))
            part.fired.append(bool(r.gate_fired))
            part.violation.append(bool(r.violation))
            part.episode.append(int(r.episode))
            arriving[0] = math.nan if r.done else float(r.curiosity)

        runner.step_listeners.append(record)
        for _ in range(episodes):
            arriving[0] = math.nan
            before = sum(part.violation)
            runner.run_episode(max_steps=max_steps)
            part.violations += sum(part.violation) > before
    finally:
        env.close()
    part.steps = len(part.fear)
    return part


SIGNAL_FIELDS = ("fear", "cost", "sigma", "curiosity", "tau", "fired", "violation", "episode")
""":class:`SignalPart`'s per-step lists, in order."""


def ground_row(
    ground: str, parts: Sequence[SignalPart], gates: Sequence[dict[str, float]], horizon_steps: int
) -> GroundRow:
    """Pool a ground's scenarios (episodes kept apart by scenario) into its row."""
    episode = np.concatenate([np.asarray(p.episode, int) + 1_000_000 * k for k, p in enumerate(parts)])
    violation = np.concatenate([np.asarray(p.violation, bool) for p in parts])
    fear = np.concatenate([np.asarray(p.fear, float) for p in parts])
    curiosity = np.concatenate([np.asarray(p.curiosity, float) for p in parts])
    cost = np.concatenate([np.asarray(p.cost, float) for p in parts])
    sigma = np.concatenate([np.asarray(p.sigma, float) for p in parts])
    tau = np.concatenate([np.asarray(p.tau, float) for p in parts])
    fired = np.concatenate([np.asarray(p.fired, bool) for p in parts])
    label = labels_within(violation, episode, horizon_steps)
    return GroundRow(
        ground=ground,
        scenarios=list(dict.fromkeys(p.scenario for p in parts)),
        episodes=sum(p.episodes for p in parts),
        steps=len(fear),
        violations=sum(p.violations for p in parts),
        positives=int(label.sum()),
        fear_auroc=auroc(fear, label),
        cost_auroc=auroc(cost, label),
        sigma_auroc=auroc(sigma, label),
        curiosity_auroc=auroc(curiosity, label),
        fire_before_violation=float(fired[label].mean()) if label.any() else math.nan,
        fire_elsewhere=float(fired[~label].mean()) if (~label).any() else math.nan,
        curiosity_mean=float(np.nanmean(curiosity)) if np.isfinite(curiosity).any() else math.nan,
        tau_mean=float(np.nanmean(tau)) if np.isfinite(tau).any() else math.nan,
        gate=pool_points(gates) if gates else {},
        parts=list(parts),
    )


class Cache:
    """Measured parts by key, in one JSON file, written after each part (a stopped run resumes from it). The key names
    the run, scenario, seeds and sizes, not the code: delete the file when a family's generator or the run changes."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.data: dict[str, Any] = {}
        if path is not None and path.is_file():
            self.data = json.loads(path.read_text())

    def get(self, key: str, compute: Callable[[], Any], cached_only: bool = False) -> Any:
        """The part under ``key``, measured now unless cached (``cached_only``: None instead of measuring)."""
        if key not in self.data:
            if cached_only:
                return None
            self.data[key] = compute()
            if self.path is not None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.path.write_text(json.dumps(self.data))
        return self.data[key]


def _share(total: int, parts: int) -> list[int]:
    """``total`` split into ``parts`` nearly equal whole shares."""
    return [total // parts + (i < total % parts) for i in range(parts)]


def generalisation_table(
    run: str | Path,
    sim: str,
    grounds: Mapping[str, Sequence[str]],
    episodes: int,
    gate_episodes: int,
    *,
    horizon_s: float = 1.0,
    max_steps: int | None = None,
    first_seed: int = EVAL_SEED,
    cache: Path | None = None,
    cached_only: bool = False,
    gate_settings: Mapping[str, Any] | None = None,
) -> list[GroundRow]:
    """One row per ground (a name and its scenarios): ``episodes`` for the signals and ``gate_episodes`` for the gate
    with the scripted expert (0: not measured), split evenly among the ground's scenarios, on seeds from
    ``first_seed``, in chunks of :data:`CHUNK` episodes (seeds as one run would use them); chunks already in
    ``cache`` are not measured again, and with ``cached_only`` only they are used (a ground with none is left out).
    ``gate_settings``: :class:`~core.sage.config.GateConfig` settings over the run's own gate (an ablation, e.g.
    ``use_curiosity=False``); they are part of the cache's keys.
    """
    import sims
    from studies.envs import env_factory

    descriptor = sims.descriptor(sim)
    make = env_factory(sim)
    horizon_steps = max(1, round(horizon_s / descriptor.dt))
    store = Cache(cache)
    run_key = cache_run_key(run)
    agent: list[Any] = []

    def loaded() -> Any:
        if not agent:
            agent.append(load_agent(run))
        return agent[0]

    # what one chunk measures, bound below to its scenario, size and seed by functools.partial (which takes them at
    # once, while the loop's variables move on)
    def signal_part(scenario: str, n: int, seed: int) -> dict[str, Any]:
        return asdict(collect_signals(loaded(), lambda: make(scenario), scenario, n, max_steps, seed, gate_settings))

    def gate_part(scenario: str, n: int, seed: int) -> dict[str, float]:
        loaded_agent = loaded()
        gate = loaded_agent.make_gate(**dict(gate_settings or {}))
        return run_gated(loaded_agent, lambda: make(scenario), gate, n, max_steps, first_seed=seed)

    rows = []
    for ground, scenarios in grounds.items():
        if not scenarios:
            raise ValueError(f"ground {ground!r} has no scenarios")
        parts, gates = [], []
        shares = list(
            zip(scenarios, _share(episodes, len(scenarios)), _share(gate_episodes, len(scenarios)), strict=True)
        )
        for scenario, _, _ in shares:
            descriptor.scenario_kwargs(scenario)  # a clear error for a bad name before anything runs
        # chunk by chunk, each scenario in turn, so that a run stopped early leaves a balanced sample in the cache
        for offset in range(0, max(max(n, g) for _, n, g in shares), CHUNK):
            for scenario, n_signal, n_gate in shares:
                key = f"{run_key}{_settings_tag(gate_settings)}|{sim}|{scenario}|{max_steps}|{first_seed + offset}"
                size = min(CHUNK, n_signal - offset)
                if size > 0:
                    part = store.get(
                        f"signals|{key}|{size}",
                        functools.partial(signal_part, scenario, size, first_seed + offset),
                        cached_only,
                    )
                    if part is not None:
                        parts.append(SignalPart(**part))
                size = min(CHUNK, n_gate - offset)
                if size > 0:
                    gate = store.get(
                        f"gate|{key}|{size}",
                        functools.partial(gate_part, scenario, size, first_seed + offset),
                        cached_only,
                    )
                    if gate is not None:
                        gates.append(gate)
        if not parts:
            continue
        rows.append(ground_row(ground, parts, gates, horizon_steps))
    return rows


def cache_run_key(run: str | Path) -> str:
    """The cache keys' name of a run: its path and a digest of its checkpoint and configuration, so that a policy
    folder whose gate or weights changed (a default refitted in place) never reuses the old one's episodes."""
    import hashlib

    path = Path(run)
    folder = path.parent if path.is_file() else path
    digest = hashlib.sha256()
    for name in ("checkpoint.pt", "config.json"):
        if (folder / name).is_file():
            digest.update((folder / name).read_bytes())
    if path.is_file() and path.name != "checkpoint.pt":
        digest.update(path.read_bytes())
    return f"{run}#{digest.hexdigest()[:12]}"


def _settings_tag(gate_settings: Mapping[str, Any] | None) -> str:
    """The cache key's mark of gate settings over the run's own ("" for none: the keys of a plain run stay)."""
    if not gate_settings:
        return ""
    return "|gate:" + ",".join(f"{k}={gate_settings[k]}" for k in sorted(gate_settings))


def ugv_rows_by_movers(
    cache: Path,
    run: str | Path,
    scenario: str = "ugv-fields:test",
    max_steps: int | None = None,
    horizon_s: float = 1.0,
    gate_settings: Mapping[str, Any] | None = None,
    seeds: range | None = None,
) -> list[GroundRow]:
    """The cached signal chunks of a ``ugv-fields`` ground, regrouped by how many movers each episode's field had
    (0, 1, 2 or more): the gate's signals on fields with several movers, the issue's hardest case. Each episode's
    field is found again from its seed (the chunk's first seed plus the episode's index), as the env drew it.
    ``seeds``: only the chunks whose first seed lies in it (one table's block of a cache that holds several)."""
    import sims
    from sims.ugv.env import UGVEnv

    store = Cache(cache)
    prefix = f"signals|{cache_run_key(run)}{_settings_tag(gate_settings)}|ugv|{scenario}|{max_steps}|"
    env = sims.descriptor("ugv").make(scenario)
    groups: dict[str, list[SignalPart]] = {"0 movers": [], "1 mover": [], "2-3 movers": []}
    try:
        for key, value in store.data.items():
            if not key.startswith(prefix):
                continue
            first_seed = int(key[len(prefix) :].split("|")[0])
            if seeds is not None and first_seed not in seeds:
                continue
            part = SignalPart(**value)
            episodes = np.asarray(part.episode)
            for episode in sorted(set(part.episode)):
                env.reset(seed=first_seed + episode)
                inner = env.unwrapped
                assert isinstance(inner, UGVEnv) and inner.layout is not None  # reset built the layout
                movers = len(inner.layout.movers)
                name = "0 movers" if movers == 0 else "1 mover" if movers == 1 else "2-3 movers"
                keep = np.flatnonzero(episodes == episode)
                violated = any(part.violation[i] for i in keep)
                groups[name].append(
                    SignalPart(
                        scenario,
                        1,
                        len(keep),
                        int(violated),
                        *([getattr(part, f)[i] for i in keep] for f in SIGNAL_FIELDS),
                    )
                )
    finally:
        env.close()
    horizon_steps = max(1, round(horizon_s / sims.descriptor("ugv").dt))
    return [ground_row(name, parts, [], horizon_steps) for name, parts in groups.items() if parts]


NOVELTY_SIGNALS = ("curiosity", "sigma", "cost", "fear")


def novelty(unseen: GroundRow, seen: GroundRow) -> dict[str, float]:
    """How well each signal tells a step on unseen ground from one on seen ground: its AUROC with the unseen steps as
    positives (0.5: no better than chance; an epistemic term that rises off the training distribution scores high)."""
    out = {}
    for name in NOVELTY_SIGNALS:
        values = [np.concatenate([np.asarray(getattr(p, name), float) for p in row.parts]) for row in (unseen, seen)]
        label = np.concatenate([np.ones(len(values[0]), bool), np.zeros(len(values[1]), bool)])
        out[name] = auroc(np.concatenate(values), label)
    return out


def _num(value: float, digits: int = 3) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _pct(value: float) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.0%}"


def render(
    rows: Sequence[GroundRow],
    *,
    sim: str,
    run: str,
    horizon_s: float,
    command: str,
    commit: str,
    by_movers: Sequence[GroundRow] = (),
    host: str | None = None,
    wall_s: float | None = None,
) -> str:
    """The markdown section of one simulator's table (and, given ``by_movers``, the unseen signals by movers).
    ``host`` and ``wall_s``: the processor that ran the command and its wall time, stated in the header."""
    where = ""
    if host is not None and wall_s is not None:
        where = (
            f" on {host} (the CPU), {wall_s / 60:.1f} min wall for this command (episodes already in its cache are "
            "read, not driven again)"
        )
    lines = [
        f"## {sim}: {run}",
        "",
        f"Made by `{command}` at commit `{commit}`{where}. Label: a violation within {horizon_s:g} s. Gate row: the",
        "policy with its own gate and the scripted expert; episodes with a violation (95% Wilson interval) at its",
        "takeover rate.",
        "",
        *_table(rows),
    ]
    unseen = next((r for r in rows if r.ground.startswith("unseen")), None)
    seen = next((r for r in rows if r.ground.startswith("seen")), None)
    if unseen is not None and seen is not None and unseen.parts and seen.parts:
        scores = novelty(unseen, seen)
        names = {"curiosity": "curiosity", "sigma": "σ̂", "cost": "ĉ", "fear": "fear"}
        lines += [
            "",
            "Telling a step on unseen ground from one on seen ground (AUROC, unseen steps positive; 0.5 is chance): "
            + ", ".join(f"{names[k]} {_num(v)}" for k, v in scores.items())
            + ".",
        ]
    if by_movers:
        lines += [
            "",
            "### The unseen ground's episodes without the expert, by movers in the field",
            "",
            *_table(by_movers),
        ]
    return "\n".join(lines) + "\n"


def _table(rows: Sequence[GroundRow]) -> list[str]:
    lines = [
        "| ground | scenarios | episodes (steps) | episodes with a violation, no expert "
        "| fear AUROC (its parts ĉ, σ̂) | curiosity AUROC "
        "| gate firing: before a violation / elsewhere | curiosity (mean) | τ (mean) "
        "| gate + expert: episodes with a violation [95%] | takeover |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        if row.gate:
            violations, episodes = row.gate_violations
            low, high = violation_interval(row.gate)
            gate = f"{violations} of {episodes} ({_pct(violations / episodes)}) [{_pct(low)}, {_pct(high)}]"
            takeover = _pct(row.gate["takeover_rate"])
        else:
            gate = takeover = "–"
        lines.append(
            f"| {row.ground} | {', '.join(row.scenarios)} | {row.episodes} ({row.steps}) | {row.violations} "
            f"| {_num(row.fear_auroc)} ({_num(row.cost_auroc, 2)}, {_num(row.sigma_auroc, 2)}) "
            f"| {_num(row.curiosity_auroc)} "
            f"| {_pct(row.fire_before_violation)} / {_pct(row.fire_elsewhere)} | {_num(row.curiosity_mean)} "
            f"| {_num(row.tau_mean, 4)} | {gate} | {takeover} |"
        )
    return lines


def write_section(out: Path, sim: str, section: str) -> None:
    """Put ``section`` into ``out`` in place of that simulator's earlier one (other simulators' stay)."""
    head = (
        "# Generalisation: seen against unseen ground\n\n"
        "Generated by `python -m studies.generalisation`; do not edit.\n"
    )
    text = out.read_text() if out.is_file() else head
    marker = f"## {sim}: "
    before: list[str] = []
    after: list[str] = []
    kept, skipping = before, False
    for line in text.splitlines():
        if line.startswith("## "):
            skipping = line.startswith(marker)
            if skipping:
                kept = after  # the simulators after this one's old section stay after the new one
        if not skipping:
            kept.append(line)
    parts = ["\n".join(before).rstrip("\n") + "\n\n" + section.rstrip("\n") + "\n"]
    if after:
        parts.append("\n" + "\n".join(after).strip("\n") + "\n")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("".join(parts))


EXTRA_GROUNDS: dict[str, list[tuple[str, Path]]] = {
    "ugv": [
        (
            "Test fields with two or more movers (the issue's hardest case)",
            Path("results/generalisation/scratch-crowded.md"),
        ),
        (FRESH_TITLE, Path("results/generalisation/fresh-ugv.md")),
        (
            "Test fields with two or more movers, a fresh draw (from 11,000,000)",
            Path("results/generalisation/fresh-ugv-2plus.md"),
        ),
    ],
    **{
        sim: [(FRESH_TITLE, Path(f"results/generalisation/fresh-{sim}.md"))]
        for sim in ("pedestrian", "sumo", "highway")
    },
}
"""Per simulator, grounds measured by a command of their own into a committed file (its ``--out``, e.g.
``results/generalisation/run-ugv-crowded.sh``) that :data:`DEFAULT_OUT` carries as subsections of the simulator's
section, each titled as here and made from that file's section (:func:`attach_extras`)."""


def _extra_subsection(sim: str, title: str, file: Path) -> list[str]:
    """``file``'s section of ``sim`` as a subsection titled ``title`` (its own subsections one level down)."""
    lines = file.read_text().splitlines()
    starts = [i for i, line in enumerate(lines) if line.startswith(f"## {sim}: ")]
    if not starts:
        raise ValueError(f"{file} has no {sim} section")
    body = []
    for line in lines[starts[0] + 1 :]:
        if line.startswith("## "):
            break
        body.append("#" + line if line.startswith("### ") else line)
    while body and not body[-1].strip():
        body.pop()
    return [f"### {title}", *body]


def attach_extras(out: Path, sim: str, root: Path = Path()) -> None:
    """Put ``sim``'s :data:`EXTRA_GROUNDS` (files under ``root``) at the end of its section in ``out``, in place of
    those subsections' earlier text (the rest of the document stays); a simulator without extras is left as it is."""
    extras = EXTRA_GROUNDS.get(sim, [])
    if not extras:
        return
    made = [_extra_subsection(sim, title, root / file) for title, file in extras]
    titles = {f"### {title}" for title, _ in extras}
    lines = out.read_text().splitlines()
    starts = [i for i, line in enumerate(lines) if line.startswith(f"## {sim}: ")]
    if not starts:
        raise ValueError(f"{out} has no {sim} section to attach {', '.join(str(f) for _, f in extras)} to")
    start = starts[0]
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
    kept, skipping = [], False
    for line in lines[start:end]:
        if line.startswith(("### ", "## ")):
            skipping = line in titles
        if not skipping:
            kept.append(line)
    while kept and not kept[-1].strip():
        kept.pop()
    for subsection in made:
        kept += ["", *subsection]
    after = ["", *lines[end:]] if end < len(lines) else []
    out.write_text("\n".join([*lines[:start], *kept, *after]) + "\n")


def default_grounds(
    run: str | Path,
    sim: str,
    family_train: bool = False,
    unseen: str | None = None,
    seen: Sequence[str] | None = None,
) -> dict[str, list[str]]:
    """Unseen: the family's test split (measured first: the question); seen: the run's training scenarios; with
    ``family_train``, the family's train split too (ground a refit may be fitted on; for a run not fitted on it, a
    check that the two splits are alike). ``unseen``: another scenario name for the unseen ground (e.g.
    ``ugv-fields:test:2+``, the test fields with two or more movers). ``seen``: other scenarios for the seen ground,
    e.g. a refit on the family's train split measured on the built-in scenarios its baseline was (same seeds)."""
    if sim not in FAMILIES:
        raise ValueError(f"no procedural family for {sim!r} yet; families exist for {', '.join(FAMILIES)}")
    from core.agents import read_run_config

    training = [str(s) for s in read_run_config(run)["run"]["scenarios"]]
    unseen = unseen or f"{FAMILIES[sim]}:test"
    if seen:
        grounds = {f"unseen ({unseen})": [unseen], "seen (scenarios given)": list(seen)}
    else:
        grounds = {f"unseen ({unseen})": [unseen], "seen (training scenarios)": training}
    if family_train:
        grounds[f"family train ({FAMILIES[sim]}:train)"] = [f"{FAMILIES[sim]}:train"]
    return grounds


def gate_settings_of(pairs: Sequence[str], sim: str | None = None) -> dict[str, Any]:
    """``gate.KEY=VALUE`` pairs as :class:`~core.sage.config.GateConfig` settings; another section is a ValueError.
    ``sim``: the simulator whose contact floors a setting that needs them brings along (as ``sage gate`` does)."""
    import sims
    from core.sage.config import parse_gate_settings

    keys = []
    for pair in pairs:
        if not pair.startswith("gate."):
            raise ValueError(f"{pair!r}: this study takes gate settings only (gate.KEY=VALUE)")
        keys.append(pair.removeprefix("gate."))
    return parse_gate_settings(keys, sims.descriptor(sim).contact_floors if sim else ())


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.generalisation", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sim", default="ugv")
    parser.add_argument("--run", help="run folder or checkpoint (default: policies/<sim>-default)")
    parser.add_argument("--episodes", type=int, default=60, help="episodes a ground for the signals")
    parser.add_argument("--gate-episodes", type=int, help="episodes a ground for the gate row (default: --episodes)")
    parser.add_argument("--horizon", type=float, default=1.0, help="seconds: the label's 'violation within'")
    parser.add_argument("--max-steps", type=int)
    parser.add_argument(
        "--first-seed",
        type=int,
        default=EVAL_SEED,
        help=f"the first episode seed of every ground (default {EVAL_SEED:,}, the table's; another block draws other "
        f"episodes, e.g. {FRESH_SEED:,} for a fresh draw of the test split that no choice has read)",
    )
    parser.add_argument("--family-train", action="store_true", help="a row for the family's train split too")
    parser.add_argument("--unseen", help="the unseen ground's scenario (default: the family's test split)")
    parser.add_argument(
        "--seen",
        action="append",
        default=[],
        help="the seen ground's scenarios (repeatable, comma lists; default: the run's training scenarios)",
    )
    parser.add_argument(
        "--by-movers", action="store_true", help="ugv: also the unseen signals by movers in the field (from the cache)"
    )
    parser.add_argument(
        "--cached-only", action="store_true", help="write the table from the cache's chunks, measuring nothing"
    )
    parser.add_argument(
        "--grounds",
        choices=("both", "unseen", "seen"),
        default="both",
        help="measure only one ground (a long run in two parts: the cache keeps the first for the second)",
    )
    parser.add_argument(
        "--set",
        dest="settings",
        action="append",
        default=[],
        metavar="gate.KEY=VALUE",
        help="a gate setting over the run's own (repeatable; an ablation, e.g. gate.use_curiosity=false)",
    )
    parser.add_argument(
        "--extras-only",
        action="store_true",
        help="measure nothing: put the simulator's extra grounds (EXTRA_GROUNDS' committed files) into --out again",
    )
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument(
        "--cache", type=Path, help="JSON of measured parts (default: results/generalisation/<sim>.json)"
    )
    args = parser.parse_args(argv)
    run = args.run or f"policies/{args.sim}-default"
    if args.extras_only:
        try:
            attach_extras(args.out, args.sim)
        except (ValueError, FileNotFoundError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(f"wrote {args.sim}'s extra grounds into {args.out}")
        return 0
    gate_episodes = args.episodes if args.gate_episodes is None else args.gate_episodes
    if args.episodes < 1 or gate_episodes < 0:
        print("--episodes must be at least 1 and --gate-episodes at least 0", file=sys.stderr)
        return 2
    if args.first_seed < 0:
        print("--first-seed must be at least 0", file=sys.stderr)
        return 2
    try:
        seen = [name.strip() for value in args.seen for name in value.split(",") if name.strip()]
        grounds = default_grounds(run, args.sim, args.family_train, args.unseen, seen)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        gate_settings = gate_settings_of(args.settings, args.sim)
    except ValueError as exc:
        print(f"error: --set {exc}", file=sys.stderr)
        return 2
    if gate_settings and not args.cached_only:
        try:  # the settings and the run together: refused here in one line, not inside the first drive
            load_agent(run).make_gate(**gate_settings)
        except ValueError as exc:
            print(f"error: --set {exc}", file=sys.stderr)
            return 2
    if args.grounds != "both":
        grounds = {name: scenarios for name, scenarios in grounds.items() if name.startswith(args.grounds)}
    from studies.results import current_commit

    commit = current_commit()  # the code that measures: taken before the run, which may outlast later commits
    cache = args.cache or Path("results/generalisation") / f"{args.sim}.json"
    started = time.monotonic()
    rows = generalisation_table(
        run,
        args.sim,
        grounds,
        args.episodes,
        gate_episodes,
        horizon_s=args.horizon,
        max_steps=args.max_steps,
        first_seed=args.first_seed,
        cache=cache,
        cached_only=args.cached_only,
        gate_settings=gate_settings,
    )
    command = "python -m studies.generalisation " + " ".join(argv if argv is not None else sys.argv[1:])
    by_movers: list[GroundRow] = []
    if args.by_movers and args.sim == "ugv":
        by_movers = ugv_rows_by_movers(
            cache,
            run,
            max_steps=args.max_steps,
            horizon_s=args.horizon,
            gate_settings=gate_settings,
            seeds=range(args.first_seed, args.first_seed + args.episodes),
        )
    section = render(
        rows,
        sim=args.sim,
        run=run,
        horizon_s=args.horizon,
        command=command.strip(),
        commit=commit,
        by_movers=by_movers,
        host=processor_name(),
        wall_s=time.monotonic() - started,
    )
    write_section(args.out, args.sim, section)
    print(section)
    if args.out.resolve() == DEFAULT_OUT.resolve():
        try:
            attach_extras(args.out, args.sim)  # the docs' section carries its extra grounds again
        except (ValueError, FileNotFoundError) as exc:
            print(f"error: the extra grounds: {exc}", file=sys.stderr)
            return 2
        update_readme(doc=args.out)  # the README's summary row of this simulator, from the section just written
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

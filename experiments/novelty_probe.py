"""Which per-step signal of the world model rises on ground it was not trained on? (issue #60, curiosity target)

The generalisation table finds curiosity *lower* on unseen UGV fields than on the training scenarios (1.652 against
1.731) and telling their steps apart worse than chance (AUROC 0.449). Curiosity, the model's prediction error, also
rises with movers (1.22 on unseen fields with none, 2.32 with two or more), so the two grounds' mixes of movers may
hide a novelty signal. This probe records, for the policy with its own gate and no expert, on the training scenarios
(seen) and on ``ugv-fields:test`` (unseen), every step's

- ``curiosity``: C on arriving at the state (as the gate scores it);
- ``epistemic``: the members' disagreement about the next state, sqrt(mean over channels of the members' variance
  of the predicted change, in units of the change's std): the ensemble's own measure of "not seen in training",
  without the aleatoric part that a mover's unpredictability carries;
- ``novelty``: how far the state (with its motion input) lies from the reference set of training states that a
  calibration for ``gate.curiosity_signal=novelty`` kept (:mod:`core.sage.novelty`; NaN for a run without one: make
  one with ``sage gate refit-bounds ... --set gate.curiosity_signal=novelty --set gate.curiosity_reference=fitted``);
- ``fear`` and ``sigma`` (σ̂) for comparison;

and prints each signal's AUROC for "this step is on unseen ground", overall and within strata of the episode's
movers (0, or 1 and more), where the grounds' mover mixes cannot confound it.

    .venv/bin/python -m experiments.novelty_probe --episodes 60 --out docs/notes/novelty_probe.md

Not a unit test: about a minute per 50 episodes on one core.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from core.agents import load_agent
from core.loop import Runner, StepRecord
from core.metrics import auroc
from core.motion import motion_between
from core.sage.novelty import novelty_features

SEEN = ("1", "2", "sims/ugv/scenarios/clutter.yaml", "sims/ugv/scenarios/movers.yaml")
UNSEEN = ("ugv-fields:test",)
SIGNALS = ("curiosity", "epistemic", "novelty", "fear", "sigma")
FIRST_SEED = 5_000_000


def epistemic_disagreement(world_model: Any, obs: np.ndarray, action: np.ndarray, motion: np.ndarray | None) -> float:
    """The members' spread about the next state (:meth:`~core.sage.world_model.EnsembleWorldModel.disagreement`)."""
    with torch.inference_mode():
        o = torch.from_numpy(np.asarray(obs, np.float32)).view(1, -1)
        a = torch.from_numpy(np.asarray(action, np.float32)).view(1, -1)
        m = None if motion is None else torch.from_numpy(np.asarray(motion, np.float32)).view(1, -1)
        return float(world_model.disagreement(o, a, m)[0])


def state_novelty(world_model: Any, obs: np.ndarray, motion: np.ndarray | None) -> float:
    """The state's novelty against the model's reference set (:mod:`core.sage.novelty`); NaN without one."""
    reference = world_model.novelty_reference()
    if reference is None:
        return math.nan
    with torch.inference_mode():
        o = torch.from_numpy(np.asarray(obs, np.float32)).view(1, -1)
        m = None if motion is None else torch.from_numpy(np.asarray(motion, np.float32)).view(1, -1)
        return float(reference(novelty_features(o, m, world_model.motion))[0])


def collect(run: str, scenario: str, episodes: int, first_seed: int) -> dict[str, list[float]]:
    """Every step's signals and its episode's mover count, the policy with its gate and no expert."""
    import sims

    agent = load_agent(run)
    gate = agent.make_gate()
    wm = agent.world_model
    assert wm is not None, f"{run} has no world model: nothing to probe"
    env = sims.descriptor("ugv").make(scenario)
    out: dict[str, list[float]] = {name: [] for name in (*SIGNALS, "movers")}
    state: dict[str, Any] = {"previous": None, "arriving": math.nan}

    def record(r: StepRecord) -> None:
        previous = state["previous"]
        motion = None if previous is None else motion_between(previous.reshape(1, -1), r.obs.reshape(1, -1), wm.scan)
        out["epistemic"].append(epistemic_disagreement(wm, r.obs, r.action, motion))
        out["novelty"].append(state_novelty(wm, r.obs, motion))
        out["curiosity"].append(state["arriving"])
        out["fear"].append(float(r.fear))
        out["sigma"].append(float(gate.detail.sigma))
        out["movers"].append(-1)  # the episode's mover count, set once it ends
        state["previous"] = None if r.done else np.asarray(r.obs, np.float32)
        state["arriving"] = math.nan if r.done else float(r.curiosity)

    try:
        runner = Runner(env, agent.policy, gate, None, seed=first_seed, deterministic=True)
        runner.step_listeners.append(record)
        for _ in range(episodes):
            state["previous"], state["arriving"] = None, math.nan
            runner.run_episode()
            # the layout of the episode just driven (the env keeps it until the next reset)
            layout = getattr(env.unwrapped, "layout", None)
            movers = len(layout.movers) if layout is not None else 0
            _relabel_last_episode(out, runner_steps_of_last_episode(out), movers)
    finally:
        env.close()
    return out


def runner_steps_of_last_episode(out: dict[str, list[float]]) -> int:
    """Steps recorded since the last relabelling (their mover count is the placeholder -1)."""
    n = 0
    for value in reversed(out["movers"]):
        if value != -1:
            break
        n += 1
    return n


def _relabel_last_episode(out: dict[str, list[float]], steps: int, movers: int) -> None:
    for i in range(len(out["movers"]) - steps, len(out["movers"])):
        out["movers"][i] = movers


def ground(run: str, scenarios: Sequence[str], episodes: int) -> dict[str, np.ndarray]:
    """A ground's steps pooled over its scenarios, ``episodes`` shared among them."""
    pooled: dict[str, list[float]] = {name: [] for name in (*SIGNALS, "movers")}
    share = [episodes // len(scenarios) + (i < episodes % len(scenarios)) for i in range(len(scenarios))]
    for i, (scenario, n) in enumerate(zip(scenarios, share, strict=True)):
        part = collect(run, scenario, n, FIRST_SEED + 1000 * i)
        for name in pooled:
            pooled[name] += part[name]
    return {name: np.asarray(values, float) for name, values in pooled.items()}


def separation(unseen: dict[str, np.ndarray], seen: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """Each signal's AUROC for "unseen ground" overall and per mover stratum (NaN steps left out)."""
    strata = {
        "all": (np.ones_like(unseen["movers"], bool), np.ones_like(seen["movers"], bool)),
        "0 movers": (unseen["movers"] == 0, seen["movers"] == 0),
        "1+ movers": (unseen["movers"] >= 1, seen["movers"] >= 1),
    }
    table: dict[str, dict[str, float]] = {}
    for stratum, (mask_u, mask_s) in strata.items():
        row: dict[str, float] = {"steps unseen": float(mask_u.sum()), "steps seen": float(mask_s.sum())}
        for name in SIGNALS:
            u, s = unseen[name][mask_u], seen[name][mask_s]
            u, s = u[np.isfinite(u)], s[np.isfinite(s)]
            if len(u) == 0 or len(s) == 0:
                row[name] = math.nan
                continue
            label = np.concatenate([np.ones(len(u), bool), np.zeros(len(s), bool)])
            row[name] = auroc(np.concatenate([u, s]), label)
            row[f"{name} mean unseen/seen"] = float(np.mean(u) / np.mean(s)) if np.mean(s) else math.nan
        table[stratum] = row
    return table


def render(table: dict[str, dict[str, float]], command: str, commit: str) -> str:
    lines = [
        f'Made by `{command}` at commit `{commit}`. AUROC of each signal for "the step is on unseen ground" '
        "(0.5: chance; above: higher on unseen), and the ratio of its means unseen / seen.",
        "",
        "| stratum | steps unseen / seen | " + " | ".join(f"{s} AUROC (mean ratio)" for s in SIGNALS) + " |",
        "|---|---|" + "---|" * len(SIGNALS),
    ]
    for stratum, row in table.items():
        cells = [
            f"{row[s]:.3f} ({row.get(f'{s} mean unseen/seen', math.nan):.2f})" if math.isfinite(row[s]) else "–"
            for s in SIGNALS
        ]
        lines.append(
            f"| {stratum} | {int(row['steps unseen'])} / {int(row['steps seen'])} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", default="policies/ugv-default")
    parser.add_argument("--episodes", type=int, default=60, help="episodes a ground (shared among its scenarios)")
    parser.add_argument("--out", type=Path, default=None, help="write the table here (markdown)")
    args = parser.parse_args(argv)
    seen = ground(args.run, SEEN, args.episodes)
    unseen = ground(args.run, UNSEEN, args.episodes)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    command = "python -m experiments.novelty_probe " + " ".join(sys.argv[1:] if argv is None else argv)
    text = render(separation(unseen, seen), command.strip(), commit or "unknown")
    print(text)
    if args.out is not None:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

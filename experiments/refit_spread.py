"""How much does the gate's safety depend on which refit of the world model it runs? And does a change to the world
model (an arm: ``--set`` overrides) beat that spread?

Each arm refits a default policy's world model (``--sim``: :data:`REFITS`; on the UGV the command in
``policies/ugv-default/README.md``: the same demonstrations, episodes and label, the policy from c36823a, as there),
once per seed. Then every refit drives the gate + scripted expert table of ``experiments/calibration.py`` (its
seeds, the simulator's scenarios and fields). The table gives per arm and scenario the episodes with a violation
for each seed, their mean with a 95% t-interval over seeds, and the mean takeover rate; ``--deployed`` adds the
committed policy's own rows beside them. ``--rows`` takes an arm's rows from an earlier run's ``rows.json`` where its
refits are not kept (the report says which, and the commit they were measured at).

    .venv/bin/python -m experiments.refit_spread [--sim ugv] [--arms plain scan] [--seeds 0 1 2] [--episodes 100] \
        [--runs runs/refit-spread] [--merge] [--deployed] [--rank-episodes 150] \
        [--rows docs/notes/refit_spread/rows.json] \
        [--out DIR] [--readme docs/notes/calibration_history.md] [--block NAME] [--cpus N | --address HOST:PORT]

``--rank-episodes N`` adds how well fear ranks the steps before a violation (``sage gate evaluate``'s first table: the
policy alone with its gate watching, no expert, N episodes per scenario, "a violation within 1 s"): per arm and
scenario the AUROC of fear for each refit, its mean with a 95% t-interval, and the share of the other steps on which
the gate fires (its false alarms, what the takeover pays for).

``--merge`` also merges each arm's refits into one ensemble of all their members (``sage gate merge``: bagging over
refits, :mod:`core.merge`) and drives its gate rows beside the single refits'. It needs refits that kept their
calibration states (``calibration.npz``, since 1294db4); an arm whose refits are older is named and left unmerged.

Arms: ``plain`` (the deployed refit's settings), ``scan`` (its motion input with the previous lidar frame turned
to the current heading, :mod:`core.motion`), ``states16k`` (κ and the τ bounds from 16384 buffer states at each
fit, ``GateConfig.calibration_states``, where the deployed refit took 2048), and ``gated`` (states16k with half the
policy episodes driven as deployed, the gate handing control to the expert that yields, while the expert blind to
movers demonstrates: ``--demo-expert blind-movers --refit-gated-share 0.5``), ``conflict`` and ``conflict1s``
(states16k with the violation head's label also the near misses with movers, ``info["conflict"]`` of
``--env conflict.report=true``: holding its command the robot would touch a mover within 2 s, or 1 s, or is within
0.12 m of one, weight 1, ``world_model_config.conflict_label_weight``) and ``label1s`` (states16k with the violation
label 1 s long, ``world_model_config.violation_steps=10``, where the deployed refit's is 2 s; ``label1s-conflict``
also the near misses of ``conflict``) and ``approach`` (states16k with the scan's motion input and each sector's
rate of approach as a further input: a new model on the refit's data). The refits of
``plain`` and ``scan`` kept under ``runs/refit-spread`` were made at c68b366, before ``calibration_states``: their
2048 states were drawn with replacement, those of a rerun without (about the same noise: τ_max's sampling sd 0.035
and 0.034 on the rebuilt buffer of plain seed 0, a scratch measurement), so a rerun of ``plain`` no longer reproduces
the deployed checkpoint bit for bit. Highway's arms: ``plain``,
``lag5`` (the motion input as the mean change over the last 5 steps, 0.5 s, where plain reads the last step's),
``approach`` (each beam's approach rate as a further input, :func:`core.motion.approach_rate`: a new model, fitted
on 600 policy episodes and 40 demonstrations, about what the deployed model's chain of fits saw), ``late-brakes``
(the demonstrations by the expert with its safety forecast cut to 0.2 s, ``--env expert.horizon=0.2``: it brakes
late behind a braking leader, so they hold the rear-end collisions the test split's adversaries cause) and ``label4s``
(the violation label 4 s long, ``--set world_model_config.violation_steps=40``, where the checkpoint's is 2 s: the
expert needs a warning about a second ahead, which may come from the short headways before a leader brakes),
``conflict`` and ``conflict-half`` (the violation head's label also the simulator's traffic conflicts, weight 1 or 0.5,
``world_model_config.conflict_label_weight``: a near miss, time to contact under 3 s or a vehicle within 1.5 m) and
``conflict-ahead`` (weight 1, the label a conflict within the next second, ``world_model_config.conflict_steps=10``).

A UGV refit takes about 18 minutes of one core, a highway one about 9-16; each is a Ray task
(:func:`studies.sweep.run_tasks`) and is kept under ``--runs`` (a rerun reuses finished refits and their rows:
resumable). Not a unit test: it takes an hour on two cores.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import re
import subprocess
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

import sims
from core.sage.calibration import CALIBRATION_FILE
from experiments.calibration import table_scenarios
from studies.readme import include
from studies.spec import TrainSpec
from studies.sweep import run_tasks

ROOT = Path(__file__).resolve().parents[1]
POLICY_COMMIT = "c36823a"
"""The policy whose world model the deployed UGV refit replaced (``policies/ugv-default`` at this commit)."""
REFIT = TrainSpec(
    sim="ugv",
    scenario="1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml",
    method="sac",
    episodes=400,
    world_model_only=True,
    demo_episodes=300,
    demo_noise=0.3,
    env=["expert.yield_to_movers=false"],
    overrides=[
        "world_model_config.violation_steps=20",
        "world_model_config.cost_label_weight=0.3",
        "gate.release=1",
        # the deployed gate's two later 0-episode steps (policies/ugv-default/README.md): they change no weight,
        # but a refit's rows must be measured with the gate the committed checkpoint deploys
        "gate.hold_seconds=1",
        "gate.tau_interpolation=geometric",
    ],
    checkpoint_every=0,
    checkpoint_dtype="float16",
)
"""The refit of ``policies/ugv-default/README.md`` with its deployed gate (seed, init and out filled in per run).
The refits and rows of ``docs/notes/calibration_history.md`` made up to c19b723 had the paper's linear τ and a 5-step
hold; a refit kept under ``--runs`` from then keeps its own gate (a rerun reuses it): give a new ``--runs``."""


@dataclass(frozen=True)
class Refit:
    """How a simulator's default world model is refitted: the policy (under ``policies/``) at a commit, as --init."""

    policy: str
    commit: str
    spec: TrainSpec


REFITS = {
    "ugv": Refit("ugv-default", POLICY_COMMIT, REFIT),
    "highway": Refit(
        "highway-default",
        "1bbe18d",
        TrainSpec(
            sim="highway",
            scenario="train",
            episodes=300,
            world_model_only=True,
            demo_episodes=20,
            demo_noise=0.3,
            checkpoint_every=0,
            checkpoint_dtype="float16",
        ),
    ),
}
"""Per simulator: the refit (seed, init and out filled in per run). Highway: as steps 2 and 3 of
``policies/highway-default/README.md`` (300 policy episodes of the train split, the checkpoint's 2 s label and gate),
with 20 noisy demonstrations where they took 30, from the deployed checkpoint (1bbe18d, the gate's hysteresis set)."""
MERGED = "merged"
"""The seed slot of an arm's merged refits (``--merge``) in the measured rows."""
DEPLOYED = "deployed"
"""The arm of the committed policy's own rows (``--deployed``)."""


@dataclass(frozen=True)
class Arm:
    """What an arm changes in the refit: ``--set`` overrides added to the refit's, and other fields of its spec."""

    overrides: list[str] = dataclasses.field(default_factory=list)
    changes: dict[str, Any] = dataclasses.field(default_factory=dict)
    """:class:`TrainSpec` fields given other values (e.g. ``refit_gated_share``)."""

    def apply(self, spec: TrainSpec) -> TrainSpec:
        return spec.replace(overrides=[*spec.overrides, *self.overrides], **self.changes)

    def flags(self, spec: TrainSpec) -> str:
        """What the arm adds to (or takes from) the refit's command line."""
        words = [f"--set {item}" for item in self.overrides]
        changed = self.apply(spec)
        for name in self.changes:
            flag = next(f for f in dataclasses.fields(TrainSpec) if f.name == name).metadata.get(
                "flag", "--" + name.replace("_", "-")
            )
            before, after = getattr(spec, name), getattr(changed, name)
            if isinstance(before, list):
                words.extend(f"without {flag} {item}" for item in before if item not in after)
                words.extend(f"{flag} {item}" for item in after if item not in before)
            else:
                words.append(f"{flag} {after}")
        return " ".join(words) or "nothing"


def arms(sim: str = "ugv") -> dict[str, Arm]:
    if sim == "highway":
        # lag5: the motion input over the last 5 steps (0.5 s) instead of 1: a cut-in's lateral drift over one
        # 0.1 s step is a few centimetres of lidar range, under the jitter of a sector's minimum
        from sims.highway.env import approach_layout

        # approach: each beam's approach rate (inverse time to contact) as an input besides its range and change. The
        # old weights cannot read it, so these refits start a new model; they get about the data the deployed
        # model's chain of fits had (twice a refit's episodes and demonstrations) where plain warm-starts from it
        approach = [f"world_model_config.{key}={value}" for key, value in approach_layout().items()]
        return {
            "plain": Arm(),
            "lag5": Arm(["world_model_config.motion_lag=5"]),
            "approach": Arm(approach, {"episodes": 600, "demo_episodes": 40}),
            # late-brakes: the demonstrations by the expert with its safety forecast cut to 0.2 s (IDM alone, so it
            # brakes late behind a braking leader): collision-rich data, as the UGV's blind-to-movers demonstrations
            "late-brakes": Arm(changes={"env": ["expert.horizon=0.2"]}),
            # label4s: the violation label "within the next 40 steps" (4 s) where the checkpoint's is 2 s. Under gate
            # + expert most adversarial collisions come after a takeover 0.2-0.5 s before them, where the expert needs
            # about 1 s (experiments/escape.py); a label that reaches past the leader's braking may rank the short
            # headways that precede it
            "label4s": Arm(["world_model_config.violation_steps=40"]),
            # conflict: the violation head also learns the simulator's traffic conflicts (time to contact under 3 s or
            # a vehicle within 1.5 m; experiments/oracle_gate.py: a gate on them meets the target), many more positives
            # than collisions; conflict-half weighs them 0.5, below a real violation ahead
            "conflict": Arm(["world_model_config.conflict_label_weight=1"]),
            "conflict-half": Arm(["world_model_config.conflict_label_weight=0.5"]),
            # conflict-ahead: a conflict within the next second (10 steps) where conflict labels the conflict's own
            # steps: under gate + expert on the adversarial splits the expert is handed most cut-ins about a second
            # before contact, which is about when the conflict itself begins
            "conflict-ahead": Arm(
                ["world_model_config.conflict_label_weight=1", "world_model_config.conflict_steps=10"]
            ),
        }
    if sim != "ugv":
        return {"plain": Arm()}
    from sims.ugv.env import ego_motion_layout, scan_layout

    old_draw = "gate.calibration_states=2048"  # the deployed refit's τ estimate (before calibration_states)
    return {
        "plain": Arm([old_draw]),
        "scan": Arm([old_draw, *(f"world_model_config.{key}={value}" for key, value in scan_layout().items())]),
        "states16k": Arm(["gate.calibration_states=16384"]),
        # half the policy episodes as deployed, the gate handing control to the expert that yields (the blind one
        # still demonstrates): the hand-backs after its evasion, where UGV 3's policy collides with fear under
        # 0.02, were never in the data of a refit whose every expert was blind
        "gated": Arm(
            ["gate.calibration_states=16384"],
            {"env": [], "demo_expert": "blind-movers", "refit_gated_share": 0.5},
        ),
        # conflict: the violation head also learns the near misses with movers (sims/ugv/interaction.py: holding its
        # command the robot would touch a mover within 2 s, the label's own horizon, or is within the expert's 0.12 m
        # margin of one), as highway's deployed model does; conflict1s: within 1 s, the warning the expert needs (the
        # calibration bench's warning table), where experiments/oracle_gate.py's gate on it asks for a quarter of fear's
        # takeover on UGV 4
        "conflict": Arm(
            ["gate.calibration_states=16384", "world_model_config.conflict_label_weight=1"],
            {"env": [*REFIT.env, "conflict.report=true"]},
        ),
        "conflict1s": Arm(
            ["gate.calibration_states=16384", "world_model_config.conflict_label_weight=1"],
            {"env": [*REFIT.env, "conflict.report=true", "conflict.ttc=1"]},
        ),
        # label1s: the violation label "within the next 10 steps" (1 s, the warning the expert needs) where the
        # deployed refit's is 2 s: experiments/oracle_gate.py's gate on the true time to contact meets UGV 4's target
        # at a quarter of fear's takeover, and fear's median warning there is 3 s
        "label1s": Arm(["gate.calibration_states=16384", "world_model_config.violation_steps=10"]),
        # label1s-conflict: a collision within 1 s, or a near miss by the true time to contact (2 s), which reaches
        # further ahead where the closing speed is high (head-on) and less far where it is low (a cut-in alongside)
        "label1s-conflict": Arm(
            [
                "gate.calibration_states=16384",
                "world_model_config.violation_steps=10",
                "world_model_config.conflict_label_weight=1",
            ],
            {"env": [*REFIT.env, "conflict.report=true"]},
        ),
        # approach: each sector's rate of approach (its inverse time to contact, core.motion.approach_rate) as a
        # further model input, from the previous frame turned to the current heading (scan): the closing speed
        # that the time-to-contact gate reads. The old weights cannot read it, so these refits fit a new model on
        # the refit's data
        "approach": Arm(
            [
                "gate.calibration_states=16384",
                *(f"world_model_config.{key}={value}" for key, value in scan_layout().items()),
                "world_model_config.approach_start=0",
                "world_model_config.approach_stop=54",
            ]
        ),
        # ego: the scan's change under the robot's own motion computed (core.motion.EgoScanStep), the model learning
        # the residual: one-step range errors near obstacles of 0.1-0.5 m let the imagined robot drive through walls
        # the real one turns away from. The old weights learned the whole change, so these refits fit a new model
        "ego": Arm(
            [
                "gate.calibration_states=16384",
                *(f"world_model_config.{key}={value}" for key, value in ego_motion_layout().items()),
            ]
        ),
    }


def command(spec: TrainSpec) -> str:
    """``sage train`` with the flags of ``spec`` that differ from their defaults."""
    words = ["sage train", f"--sim {spec.sim}"]
    for f in dataclasses.fields(TrainSpec):
        value = getattr(spec, f.name)
        if f.name == "sim":
            continue
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if value == default:
            continue
        flag = f.metadata.get("flag", "--" + f.name.replace("_", "-"))
        if value is True:
            words.append(flag)
        elif isinstance(value, list):
            words.extend(f"{flag} {item}" for item in value)
        else:
            words.append(f"{flag} {value}")
    return " ".join(words)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sim", default="ugv", choices=sorted(REFITS), help="whose default world model is refitted")
    parser.add_argument(
        "--arms",
        nargs="+",
        help="ugv: plain scan states16k gated conflict conflict1s label1s label1s-conflict approach "
        "(default: plain scan); "
        "highway: plain lag5 approach late-brakes label4s conflict conflict-half conflict-ahead; else plain",
    )
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=100, help="gate + expert episodes per scenario and refit")
    parser.add_argument("--runs", type=Path, help="refits are kept here (default: runs/refit-spread, -<sim> but ugv)")
    parser.add_argument("--out", type=Path, help="default: docs/notes/refit_spread, _<sim> but ugv")
    parser.add_argument(
        "--readme",
        type=Path,
        help="also copy the result into this document's block (e.g. docs/notes/calibration_history.md)",
    )
    parser.add_argument(
        "--merge",
        action="store_true",
        help="also merge each arm's refits into one ensemble (sage gate merge) and drive its gate rows",
    )
    parser.add_argument("--deployed", action="store_true", help="also the committed policy's own gate rows")
    parser.add_argument("--block", help="--readme's block to write (default: refit-spread, -<sim> but ugv)")
    parser.add_argument(
        "--rows",
        type=Path,
        help="an earlier run's rows.json: an arm whose refits are not kept under --runs takes its rows from there",
    )
    parser.add_argument(
        "--scales",
        nargs="+",
        type=float,
        default=[],
        help="also gate rows with τ scaled by each (fear > scale · τ): the arms compared at about equal takeover",
    )
    parser.add_argument(
        "--scale-scenarios",
        nargs="+",
        help="the scenarios of the --scales rows (default: the table's; choose arms on the train splits)",
    )
    parser.add_argument(
        "--rank-episodes",
        type=int,
        default=0,
        help="also fear's ranking of the steps before a violation (AUROC, the policy alone with its gate watching) "
        "over this many episodes per scenario and refit (0: none)",
    )
    parser.add_argument("--cpus", type=int, help="cores for local Ray (default: all of them)")
    parser.add_argument("--address", help="join the Ray cluster at this address instead of starting one")
    args = parser.parse_args()
    if any(scale <= 0 for scale in args.scales):
        parser.error("--scales must be positive")
    if args.rank_episodes < 0:
        parser.error("--rank-episodes must be 0 or more")
    if len(args.seeds) < 2:
        parser.error("give at least two --seeds: the spread over refits is the point")
    settings = arms(args.sim)
    args.arms = args.arms or (["plain", "scan"] if args.sim == "ugv" else list(settings))
    unknown = [arm for arm in args.arms if arm not in settings]
    if unknown:
        parser.error(f"no arm {', '.join(unknown)} on {args.sim}; choose from {', '.join(settings)}")
    suffix = "" if args.sim == "ugv" else f"-{args.sim}"
    args.runs = (args.runs or ROOT / "runs" / f"refit-spread{suffix}").resolve()  # Ray workers: another directory
    args.out = args.out or ROOT / "docs" / "notes" / f"refit_spread{suffix.replace('-', '_')}"
    setup = REFITS[args.sim]
    init = policy_at_commit(args.runs, setup.policy, setup.commit)
    folders = {(arm, seed): args.runs / f"{arm}-s{seed}" for arm in args.arms for seed in args.seeds}
    rows_of = table_scenarios(args.sim)
    earlier = earlier_rows(args.rows) if args.rows else {}
    reused = [
        arm
        for arm in args.arms
        if not any((folders[arm, seed] / "checkpoint.pt").is_file() for seed in args.seeds)
        and all((arm, seed, scenario) in earlier for seed in args.seeds for scenario in rows_of)
    ]
    todo = [
        (arm, seed)
        for (arm, seed), folder in folders.items()
        if arm not in reused and not (folder / "checkpoint.pt").is_file()
    ]
    if todo:
        specs = [
            settings[arm].apply(setup.spec.replace(seed=seed, init=str(init), out=str(folders[arm, seed])))
            for arm, seed in todo
        ]
        run_tasks(
            refit,
            [{"spec": spec} for spec in specs],
            [f"refit {arm} seed {seed}" for arm, seed in todo],
            address=args.address,
            cpus=args.cpus,
        )
    cases: list[tuple[str, int | str, str]] = [
        (arm, seed, scenario) for arm in args.arms if arm not in reused for seed in args.seeds for scenario in rows_of
    ]
    where: dict[tuple[str, int | str], Path] = dict(folders)
    merged_arms = []
    if args.merge:
        for arm in args.arms:
            if arm in reused:
                if all((arm, MERGED, scenario) in earlier for scenario in rows_of):
                    merged_arms.append(arm)
                continue
            refits = [folders[arm, seed] for seed in args.seeds]
            if not all((folder / CALIBRATION_FILE).is_file() for folder in refits):
                continue  # refits kept from before calibration.npz: nothing to calibrate a merged model on
            where[arm, MERGED] = merged_folder(args.runs, arm, args.seeds, refits)
            cases.extend((arm, MERGED, scenario) for scenario in rows_of)
            merged_arms.append(arm)
    deployed_commit = None
    if args.deployed:
        deployed_commit = last_commit(f"policies/{setup.policy}")
        where[DEPLOYED, DEPLOYED] = policy_at_commit(args.runs, setup.policy, deployed_commit)
        cases.extend((DEPLOYED, DEPLOYED, scenario) for scenario in rows_of)
    measured = measure(
        gate_row, cases, args, where, args.episodes, lambda a, s, sc: f"gate + expert: {a} seed {s} on {sc}"
    )
    scale_scenarios = args.scale_scenarios or rows_of
    unknown_scenarios = [scenario for scenario in scale_scenarios if scenario not in rows_of]
    if unknown_scenarios:
        parser.error(f"--scale-scenarios: {', '.join(unknown_scenarios)} not in the table's {', '.join(rows_of)}")
    scaled_cases = [
        (arm, seed, scenario, scale)
        for arm in args.arms
        if arm not in reused
        for seed in args.seeds
        for scenario in scale_scenarios
        for scale in args.scales
    ]
    scaled = measure(
        gate_row,
        scaled_cases,
        args,
        where,
        args.episodes,
        lambda a, s, sc, k: f"gate (τ x {k:g}) + expert: {a} seed {s} on {sc}",
        lambda key: {"scale": key[3]},
    )
    ranked = measure(
        rank_row,
        cases if args.rank_episodes > 0 else [],
        args,
        where,
        args.rank_episodes,
        lambda a, s, sc: f"fear's ranking: {a} seed {s} on {sc}",
    )
    measured.update({key: row for key, row in earlier.items() if key[0] in reused})
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    older = sorted(
        {arm for (arm, _), folder in folders.items() if arm not in reused and predates_calibration_states(folder)}
    )
    text = report(args, settings, measured, commit.stdout.strip(), older, merged_arms, deployed_commit)
    if scaled:
        text += scaled_report(args, measured, scaled)
    if ranked:
        text += rank_report(args, ranked)
    if reused:
        source = rows_source(args)
        text[2] += f" Rows of {', '.join(reused)}: from `{source}` (at {earlier_commit(args.rows)}; refits not kept)."
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "README.md").write_text("\n".join(text) + "\n")
    (args.out / "rows.json").write_text(
        json.dumps(
            [{"arm": a, "seed": s, "scenario": sc, **measured[a, s, sc]} for a, s, sc in cases]
            + [{"arm": a, "seed": s, "scenario": sc, "scale": k, **scaled[a, s, sc, k]} for a, s, sc, k in scaled]
            + [{"arm": a, "seed": s, "scenario": sc, "rank": True, **ranked[a, s, sc]} for a, s, sc in ranked],
            indent=1,
        )
    )
    print("\n".join(text))
    if args.readme is not None:
        block = args.block or f"refit-spread{suffix}"
        include(args.readme, block, args.out / "README.md", "## Calibration of fear")
        print(f"README section '{block}' written into {args.readme}")


def measure(
    task: Callable[..., dict[str, Any]],
    keys: Sequence[tuple[Any, ...]],
    args: argparse.Namespace,
    where: dict[tuple[str, int | str], Path],
    episodes: int,
    label: Callable[..., str],
    extra: Callable[[tuple[Any, ...]], dict[str, Any]] = lambda key: {},
) -> dict[tuple[Any, ...], dict[str, Any]]:
    """``task`` (a row of :func:`gate_row` or :func:`rank_row`) for each key (arm, seed, scenario, ...) as Ray
    tasks, by key; ``extra`` gives a key's further arguments."""
    if not keys:
        return {}
    rows = run_tasks(
        task,
        [
            {"folder": str(where[key[0], key[1]]), "sim": args.sim, "scenario": key[2], "episodes": episodes}
            | extra(key)
            for key in keys
        ],
        [label(*key) for key in keys],
        address=args.address,
        cpus=args.cpus,
    )
    return dict(zip(keys, rows, strict=True))


def rows_source(args: argparse.Namespace) -> str | None:
    """``--rows`` as given, relative to the checkout where it lies in it (None: not given)."""
    rows = getattr(args, "rows", None)
    if rows is None:
        return None
    resolved = rows.resolve()
    return str(resolved.relative_to(ROOT) if resolved.is_relative_to(ROOT) else rows)


def scales_flags(args: argparse.Namespace) -> str:
    """``--scales`` and ``--scale-scenarios`` as given ("" without scaled rows)."""
    scales = getattr(args, "scales", None)
    if not scales:
        return ""
    chosen = getattr(args, "scale_scenarios", None)
    return f" --scales {' '.join(f'{k:g}' for k in scales)}" + (
        f" --scale-scenarios {' '.join(chosen)}" if chosen else ""
    )


def rank_flag(args: argparse.Namespace) -> str:
    """``--rank-episodes`` as given ("" without the ranking table)."""
    episodes = getattr(args, "rank_episodes", 0)
    return f" --rank-episodes {episodes}" if episodes else ""


def rows_flag(args: argparse.Namespace) -> str:
    source = rows_source(args)
    return "" if source is None else f" --rows {source}"


def earlier_rows(path: Path) -> dict[tuple[str, int | str, str], dict[str, Any]]:
    """The rows of an earlier run (its ``rows.json``), by (arm, seed, scenario); its τ-scaled and ranking rows left
    out."""
    return {
        (row["arm"], row["seed"], row["scenario"]): row
        for row in json.loads(path.read_text())
        if "scale" not in row and "rank" not in row
    }


def earlier_commit(rows: Path) -> str:
    """The commit an earlier run's report (the README.md beside its rows.json) names, or "an earlier commit"."""
    readme = rows.parent / "README.md"
    found = re.search(r"at commit (\w+)", readme.read_text()) if readme.is_file() else None
    return found.group(1) if found else "an earlier commit"


def last_commit(path: str) -> str:
    """The short hash of the last commit that changed ``path``."""
    out = subprocess.run(["git", "log", "-1", "--format=%h", "--", path], cwd=ROOT, capture_output=True, text=True)
    return out.stdout.strip()


def policy_at_commit(runs: Path, policy: str = "ugv-default", commit: str = POLICY_COMMIT) -> Path:
    """``policies/<policy>`` as it was at ``commit`` (a refit's --init, or the deployed policy's rows), under
    ``runs``: gate rows are cached in the folder, which must not be the committed one."""
    folder = runs / f"{policy}-{commit}"
    if not (folder / "checkpoint.pt").is_file():
        folder.mkdir(parents=True, exist_ok=True)
        for name in ("checkpoint.pt", "config.json"):
            blob = subprocess.run(
                ["git", "show", f"{commit}:policies/{policy}/{name}"],
                cwd=ROOT,
                capture_output=True,
                check=True,
            ).stdout
            (folder / name).write_bytes(blob)
    return folder


def merged_folder(runs: Path, arm: str, seeds: list[int], refits: list[Path]) -> Path:
    """The arm's refits merged into one ensemble (:func:`core.merge.merge_runs`), made once and kept."""
    from core.merge import merge_runs

    folder = runs / f"{arm}-merged-s{''.join(str(seed) for seed in seeds)}"
    if not (folder / "checkpoint.pt").is_file():
        result = merge_runs(refits, folder, dtype="float16")
        print(f"merged {arm}: {result.members} members, τ bounds {result.tau_bounds}")
    return folder


def predates_calibration_states(folder: Path) -> bool:
    """Whether a kept refit ran before ``GateConfig.calibration_states`` (its 2048 states drawn with replacement)."""
    ran_with = json.loads((folder / "config.json").read_text()).get("ran_with") or {}
    return "calibration_states" not in (ran_with.get("gate") or {})


def refit(spec: TrainSpec) -> str:
    """One Ray task: a refit, run from the checkout (its scenario paths are relative to it)."""
    import os

    import torch

    from studies.training import run_training

    torch.set_num_threads(1)
    os.chdir(ROOT)
    return str(run_training(spec).out)


def gate_row(folder: str, scenario: str, episodes: int, sim: str = "ugv", scale: float | None = None) -> dict[str, Any]:
    """One Ray task: the gate + scripted expert on a scenario (cached in the refit's folder); ``scale``: the gate
    fires where fear exceeds ``scale`` times its τ (``gate.tau_scale`` times the refit's own, the operating curve's
    knob), None: the gate as deployed."""
    from core.agents import load_agent
    from studies.calibrate import run_gated

    d = sims.descriptor(sim)
    path = scenario_path(scenario)

    def drive() -> dict[str, Any]:
        agent = load_agent(folder)
        gate = agent.make_gate() if scale is None else agent.make_gate(tau_scale=agent.gate_config().tau_scale * scale)
        point = run_gated(agent, lambda: d.make(path), gate, episodes, None, warn_steps=max(1, round(1.0 / d.dt)))
        return {
            "violations": round(point["violation_rate"] * episodes),
            "takeover": float(point["takeover_rate"]),
            "expert_driving": int(point["violations_under_expert"]),
            "handed_back": int(point["violations_handed_back"]),
        }

    name = f"gate-{Path(scenario).stem}-{episodes}{'' if scale is None else f'-tau{scale:g}'}.json"
    return cached_row(Path(folder) / name, drive)


def rank_row(folder: str, scenario: str, episodes: int, sim: str = "ugv") -> dict[str, Any]:
    """One Ray task: how well fear ranks the steps before "a violation within 1 s" with the policy alone and its gate
    watching (:func:`studies.calibrate.calibrate_run`, ``sage gate evaluate``'s seeds), cached in the refit's folder.
    AUROC is NaN where no episode had a violation."""
    from studies.calibrate import calibrate_run

    shown = Path(scenario).stem
    d = sims.descriptor(sim)
    path = scenario_path(scenario)

    def rank() -> dict[str, Any]:
        measured = calibrate_run(folder, lambda: d.make(path), d.dt, sim=sim, scenario=shown, episodes=episodes)
        return {
            "auroc": measured.scores["fear"].auroc,
            "average_precision": measured.scores["fear"].average_precision,
            "violations": measured.violations,
            "positives": measured.positives,
            "fire_before": measured.fire_rate_before_violation,
            "fire_elsewhere": measured.fire_rate_elsewhere,
        }

    return cached_row(Path(folder) / f"rank-{shown}-{episodes}.json", rank)


def scenario_path(scenario: str) -> str:
    """A scenario as the simulator's ``make`` takes it: a layout file from the checkout, else a built-in name."""
    return str(ROOT / scenario) if scenario.endswith(".yaml") else scenario


def cached_row(cache: Path, compute: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """A task's row from its cache file in the refit's folder, else computed (with its ``seconds``) and kept there:
    a rerun of the bench reuses every row it has."""
    if cache.is_file():
        return json.loads(cache.read_text())
    started = time.perf_counter()
    row = compute() | {"seconds": time.perf_counter() - started}
    cache.write_text(json.dumps(row))
    return row


def rank_report(args: argparse.Namespace, ranked: dict[tuple[str, int | str, str], Any]) -> list[str]:
    """Per scenario and arm: fear's AUROC for each refit, its mean ± 95% over seeds, the gate's firing on the steps
    not before a violation (mean over seeds) and Welch's p against the first arm; the merged and deployed models'
    own. A scenario where no refit's policy had a violation is named, not tabled."""
    sim = getattr(args, "sim", "ugv")
    shown = [arm for arm in args.arms if any(key[0] == arm for key in ranked)]
    first, others = shown[0], shown[1:]
    present = {(arm, seed) for arm, seed, _ in ranked}
    # the committed model first, then each arm's merged refits in the arms' order (as in the gate table)
    extra = [key for key in [(DEPLOYED, DEPLOYED), *((arm, MERGED) for arm in shown)] if key in present]
    lines = [
        "",
        f"#### Fear's ranking of the steps before a violation (`--rank-episodes {args.rank_episodes}`)",
        "",
        f"The policy alone with its gate watching (no expert), {args.rank_episodes} episodes per scenario and refit "
        "(`sage gate evaluate`'s seeds); label: a violation within 1 s. Per arm: fear's AUROC for each seed "
        "in the order "
        "given, its mean ± 95% over seeds, and the share of the other steps on which the gate fires (false alarms: "
        "what the takeover pays for), mean over seeds.",
        "",
        "| scenario | "
        + " | ".join(f"{arm}: AUROC per seed | {arm}: mean ± 95% | {arm}: fires elsewhere" for arm in shown)
        + "".join(
            f" | {'committed' if seed == DEPLOYED else f'{arm}, merged'}: AUROC · fires elsewhere"
            for arm, seed in extra
        )
        + "".join(f" | p, {arm} vs {first}" for arm in others)
        + " |",
        "|---|" + "---|---|---|" * len(shown) + "---|" * len(extra) + "---|" * len(others),
    ]
    quiet = []
    for scenario in table_scenarios(sim):
        if not any(key[2] == scenario for key in ranked):
            continue
        values = {arm: [ranked[arm, seed, scenario]["auroc"] for seed in args.seeds] for arm in shown}
        if all(math.isnan(v) for arm in shown for v in values[arm]):
            quiet.append(f"{sim} {Path(scenario).name}")
            continue
        cells = []
        for arm in shown:
            known = [v for v in values[arm] if not math.isnan(v)]
            elsewhere = np.nanmean([ranked[arm, seed, scenario]["fire_elsewhere"] for seed in args.seeds])
            spread = interval(known, digits=3) if len(known) > 1 else "–"
            per_seed = " · ".join("–" if math.isnan(v) else f"{v:.2f}" for v in values[arm])
            cells.append(f"{per_seed} | {spread} | {elsewhere:.0%}")
        for key in extra:
            row = ranked[(*key, scenario)]
            cells.append(
                ("–" if math.isnan(row["auroc"]) else f"{row['auroc']:.2f}") + f" · {row['fire_elsewhere']:.0%}"
            )
        for arm in others:
            a, b = ([v for v in values[name] if not math.isnan(v)] for name in (first, arm))
            cells.append(welch_p(a, b) if len(a) > 1 and len(b) > 1 else "–")
        lines.append(f"| {sim} {Path(scenario).name} | " + " | ".join(cells) + " |")
    if quiet:
        lines += ["", f"No violation with the policy alone, so nothing to rank, on: {', '.join(quiet)}."]
    return lines


def interval(values: list[float], digits: int = 1) -> str:
    """mean ± half-width of the 95% t-interval over seeds."""
    mean = float(np.mean(values))
    half = float(stats.t.ppf(0.975, len(values) - 1) * np.std(values, ddof=1) / math.sqrt(len(values)))
    return f"{mean:.{digits}f} ± {half:.{digits}f}"


def welch_p(first: list[float], second: list[float]) -> str:
    """Two-sided p of Welch's t-test that two arms' means over seeds differ (– where both have no spread)."""
    if np.std(first) == 0 and np.std(second) == 0:
        return "–"
    return f"{stats.ttest_ind(first, second, equal_var=False).pvalue:.3f}"


def report(
    args: argparse.Namespace,
    settings: dict[str, Arm],
    measured: dict[tuple[str, int | str, str], Any],
    commit: str,
    older: list[str],
    merged_arms: list[str] | None = None,
    deployed_commit: str | None = None,
) -> list[str]:
    sim = getattr(args, "sim", "ugv")
    setup = REFITS[sim]
    seeds = " ".join(str(s) for s in args.seeds)
    first, others = args.arms[0], args.arms[1:]  # each other arm is compared with the first
    merged_arms = merged_arms or []
    merge = bool(merged_arms)
    deployed = deployed_commit is not None
    header = (
        "| scenario | "
        + (f"{setup.policy} as committed: violations | takeover | " if deployed else "")
        + " | ".join(f"{arm}: violations per seed | {arm}: mean ± 95% | {arm}: takeover" for arm in args.arms)
        + "".join(f" | {arm}, merged: violations | {arm}, merged: takeover" for arm in merged_arms)
        + "".join(f" | p, {arm} vs {first}: violations · takeover" for arm in others)
        + " |"
    )
    flags = f"--sim {sim} " if sim != "ugv" else ""
    if sim == "ugv":
        each = f"`policies/ugv-default/README.md`'s command with `--seed` set (the policy from {setup.commit})"
    else:
        each = f"`{command(setup.spec)} --seed S --init policies/{setup.policy}` (the policy from {setup.commit})"
    lines = [
        "### The gate's safety over refits of the world model" + ("" if sim == "ugv" else f" ({sim})"),
        "",
        f"Generated by `python -m experiments.refit_spread {flags}--arms {' '.join(args.arms)} --seeds {seeds} "
        f"--episodes {args.episodes}{' --merge' if getattr(args, 'merge', False) else ''}"
        f"{' --deployed' if deployed else ''}{rows_flag(args)}{scales_flags(args)}{rank_flag(args)}` at commit "
        f"{commit}. "
        f"Each refit: {each}; arms add "
        + "; ".join(f"{arm}: {settings[arm].flags(setup.spec)}" for arm in args.arms)
        + (
            f" ({', '.join(older)}: refits kept from before `gate.calibration_states`, whose 2048 states were drawn "
            "with replacement)"
            if older
            else ""
        )
        + f". Gate + scripted expert over {args.episodes} episodes per scenario and refit (the calibration bench's "
        "seeds): episodes with a violation, per seed in the order given"
        + (f"; as committed: `policies/{setup.policy}` at {deployed_commit}" if deployed else "")
        + (
            f"; p: Welch's t-test of an arm's mean over seeds against {first}'s, of the violations and of the takeover"
            if others
            else ""
        )
        + (
            f"; merged: the arm's {len(args.seeds)} refits as one ensemble of all their members (`sage gate merge` of "
            "their folders, κ and τ set on the union of their calibration states"
            + (
                f"; {', '.join(a for a in args.arms if a not in merged_arms)}: refits kept from before "
                "`calibration.npz`, not merged)."
                if len(merged_arms) < len(args.arms)
                else ")."
            )
            if merge
            else "."
        ),
        "",
        header,
        "|---|"
        + ("---|---|" if deployed else "")
        + "---|---|---|" * len(args.arms)
        + "---|---|" * len(merged_arms)
        + "---|" * len(others),
    ]
    merged_total = dict.fromkeys(merged_arms, 0.0)
    deployed_total = 0.0
    totals: dict[str, list[float]] = {arm: [0.0] * len(args.seeds) for arm in args.arms}
    for scenario in table_scenarios(sim):
        cells = []
        if deployed:
            row = measured[DEPLOYED, DEPLOYED, scenario]
            deployed_total += row["violations"]
            cells.append(f"{row['violations']:.0f} | {row['takeover']:.0%}")
        counts: dict[str, list[float]] = {}
        takeovers: dict[str, list[float]] = {}
        for arm in args.arms:
            counts[arm] = [measured[arm, seed, scenario]["violations"] for seed in args.seeds]
            takeovers[arm] = [measured[arm, seed, scenario]["takeover"] for seed in args.seeds]
            takeover = np.mean(takeovers[arm])
            for i, count in enumerate(counts[arm]):
                totals[arm][i] += count
            cells.append(f"{' · '.join(f'{c:.0f}' for c in counts[arm])} | {interval(counts[arm])} | {takeover:.0%}")
        for arm in merged_arms:
            row = measured[arm, MERGED, scenario]
            merged_total[arm] += row["violations"]
            cells.append(f"{row['violations']:.0f} | {row['takeover']:.0%}")
        cells.extend(
            f"{welch_p(counts[first], counts[arm])} · {welch_p(takeovers[first], takeovers[arm])}" for arm in others
        )
        lines.append(f"| {sim} {Path(scenario).name} | " + " | ".join(cells) + " |")
    cells = [f"{deployed_total:.0f} | "] if deployed else []
    cells.extend(f"{' · '.join(f'{t:.0f}' for t in totals[arm])} | {interval(totals[arm])} | " for arm in args.arms)
    cells.extend(f"{merged_total[arm]:.0f} | " for arm in merged_arms)
    cells.extend(welch_p(totals[first], totals[arm]) for arm in others)
    lines.append("| all rows | " + " | ".join(cells) + " |")
    return lines


def scaled_report(
    args: argparse.Namespace,
    measured: dict[tuple[str, int | str, str], Any],
    scaled: dict[tuple[str, int | str, str, float], Any],
) -> list[str]:
    """The arms at about equal takeover: per scenario and τ scale (1: the gate as deployed, the table above), each
    arm's episodes with a violation (mean ± 95% over seeds) at its mean takeover rate."""
    sim = getattr(args, "sim", "ugv")
    arms_shown = sorted({arm for arm, *_ in scaled}, key=args.arms.index)
    scenarios = sorted({scenario for _, _, scenario, _ in scaled}, key=table_scenarios(sim).index)
    scales = sorted({*args.scales, 1.0}, reverse=True)
    lines = [
        "",
        f"#### At about equal takeover: τ scaled (`{scales_flags(args).strip()}`)",
        "",
        "The gate firing where fear exceeds the scale times its τ (the operating curve's knob, "
        "`gate.tau_scale` times the refit's own; 1: as deployed, the rows above), gate + scripted expert over the same "
        f"{args.episodes} episodes per refit: episodes with a violation, mean ± 95% over seeds @ mean takeover. An arm "
        "is better than another where it has fewer violations at no more takeover.",
        "",
        "| scenario | τ × | "
        + " | ".join(args.arms[i] for i in range(len(args.arms)) if args.arms[i] in arms_shown)
        + " |",
        "|---|---|" + "---|" * len(arms_shown),
    ]
    for scenario in scenarios:
        for scale in scales:
            cells = []
            for arm in arms_shown:
                rows = [
                    measured[arm, seed, scenario] if scale == 1.0 else scaled[arm, seed, scenario, scale]
                    for seed in args.seeds
                ]
                takeover = np.mean([row["takeover"] for row in rows])
                cells.append(f"{interval([row['violations'] for row in rows])} @ {takeover:.0%}")
            lines.append(f"| {sim} {Path(scenario).name} | {scale:g} | " + " | ".join(cells) + " |")
    return lines


if __name__ == "__main__":
    main()

"""SAGE-SAC update cost against our plain SAC, and our SAC against Stable-Baselines3's SAC.

Same sizes everywhere: 58 observations, 2 actions, actor and critics 2 x 128 (ReLU), 2 critics, batch 256,
one CPU thread. SAGE-SAC updates with everything on (fear in the critic target and the actor loss through
the frozen 5-member world model, the dual step, value-weighted imitation on intervention samples, actor
batches from real and virtual buffers). The methods run in interleaved rounds so that a busy machine
slows them alike; the printed ratios come from the same run.

    .venv/bin/python -m bench.bench_sac [--rounds 5] [--updates 200] [--ego] [--device] [--clock wall|cpu]
    .venv/bin/python -m bench.bench_sac --batch 256,1024 --ensemble 5,7 [--ego] [--write docs/speed.md]
    .venv/bin/python -m bench.bench_sac --before REV [--batch 256,1024] [--rounds 7] [--clock cpu]

``--ego`` adds SAGE-SAC over the ego step (the UGV default's world model, ``sims.ugv.env.ego_motion_layout``), without
and with the gate's imagined contact (``gate.imagined_contact`` with the UGV's floors: what the committed UGV policy's
recalibrated gate sets, and so what fine-tuning it trains with). The learner's one-step fear reads the violation logit
only, so without contact it runs no ego step at all; with contact each fear term moves its own batch by the compiled
step and tests it in the same call, without a graph (``core.sage.fear.rollout``, ``states_needed``;
``core._ego_kernel.contact``): twice an update, the critic target's next states and the actor's states. A
``learner_fear_horizon`` over 1 sends the actor's gradient through the step.

``--batch 256,1024 --ensemble 5,7`` measures instead what larger batches and world-model ensembles cost: our SAC at
each batch, SAGE-SAC (and with ``--ego`` over the ego step, without and with contact) at each batch and ensemble size,
the ratios to SAC at the same batch, the learners taking turns update by update (as ``--before`` below);
``--write docs/speed.md`` writes that table with the command, the commit and the processor into the file's generated
block.

``--before REV`` times instead SAGE-SAC over the ego step + contact with its update's code (``core/sage/fear.py``,
``core/sage/sac.py`` and ``core/sage/networks.py``) as git holds it at REV against it now, on one learner at each
``--batch`` (5 members), beside our SAC, in interleaved rounds: each round's now/before time and the + contact / SAC
ratios, so that a change to the update's cost is measured in one process. The contenders take turns update by update
(each update timed alone), so that the shared machine's load falls on both sides alike.

``--device`` adds SAC and SAGE-SAC on CUDA, eager and replayed as a CUDA graph (``learner.cuda_graph``), beside the CPU,
where torch sees a GPU; elsewhere it says so. ``bench/gpu_check.py`` measures batches 256 to 4096.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from core.learners import make_learner
from core.sage.config import for_method
from core.sage.learner import BaseLearner

OBS_DIM, ACT_DIM, HIDDEN, BATCH = 58, 2, 128, 256


def fill(learner: BaseLearner, n: int, rng: np.random.Generator, takeover_every: int = 10) -> None:
    obs = rng.random((n + 1, OBS_DIM)).astype(np.float32)
    for i in range(n):
        action = rng.uniform(-1, 1, ACT_DIM).astype(np.float32)
        takeover = i % takeover_every == 0
        learner.buffer.add(
            obs[i],
            action,
            float(rng.normal()),
            obs[i + 1],
            False,
            cost=float(rng.random()),
            violation=bool(rng.random() < 0.01),
            takeover=takeover,
            a_rl=rng.uniform(-1, 1, ACT_DIM).astype(np.float32),
            a_expert=action if takeover else None,
        )


def ours(
    method: str,
    rng: np.random.Generator,
    world_model: dict[str, Any] | None = None,
    batch: int = BATCH,
    device: str = "cpu",
    **overrides: Any,
) -> BaseLearner:
    cfg = for_method(method, hidden=HIDDEN, batch_size=batch, critics=2, **overrides)
    cfg.world_model_config.max_updates_per_fit = 200
    for key, value in (world_model or {}).items():
        setattr(cfg.world_model_config, key, value)
    learner = make_learner(cfg.method, cfg, OBS_DIM, ACT_DIM, seed=0, device=device)
    fill(learner, 20_000, rng)
    learner.warm = True
    if learner.world_model is not None:
        learner.fit_world_model()  # fear active, σ calibrated, virtual buffer filled
    return learner


class RandomEnv(gym.Env[np.ndarray, np.ndarray]):
    observation_space = gym.spaces.Box(0.0, 1.0, (OBS_DIM,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (ACT_DIM,), np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        return self.observation_space.sample(), {}

    def step(self, action: np.ndarray):
        return self.observation_space.sample(), 0.0, False, False, {}


def sb3(rng: np.random.Generator) -> Any:
    from stable_baselines3 import SAC
    from stable_baselines3.common.logger import configure

    model = SAC(
        "MlpPolicy",
        RandomEnv(),
        batch_size=BATCH,
        learning_starts=0,
        buffer_size=20_000,
        policy_kwargs={"net_arch": [HIDDEN, HIDDEN], "n_critics": 2},
        device="cpu",
        seed=0,
    )
    model.set_logger(configure(None, []))
    buffer = model.replay_buffer
    assert buffer is not None  # SAC's _setup_model built it
    obs = rng.random((20_001, OBS_DIM)).astype(np.float32)
    for i in range(20_000):
        buffer.add(
            obs[i : i + 1],
            obs[i + 1 : i + 2],
            rng.uniform(-1, 1, (1, ACT_DIM)),
            np.array([rng.normal()]),
            np.array([False]),
            [{}],
        )
    return model


CLOCKS: dict[str, Callable[[], float]] = {"wall": time.perf_counter, "cpu": time.process_time}
"""``--clock``: wall time, or this process's CPU time (one thread does the work: on a machine whose other processes
want more cores than it has, the wall clock also counts the time the update waited for a core)."""


def rate(
    fn: Callable[[], object],
    n: int,
    sync: Callable[[], None] | None = None,
    clock: Callable[[], float] = time.perf_counter,
) -> float:
    """Updates per second over ``n`` calls (``sync``: wait for the device's queued work before reading the clock)."""
    if sync is not None:
        sync()
    start = clock()
    for _ in range(n):
        fn()
    if sync is not None:
        sync()
    return n / (clock() - start)


def device_rows(rounds: int, updates: int) -> None:
    """``--device``: SAC and SAGE-SAC updates on the CPU (one thread), on CUDA, and on CUDA replayed as a graph
    (``learner.cuda_graph``), side by side, or a line saying that this machine has no CUDA."""
    from core.device import cuda_available, device_name, processor_name

    if not cuda_available():
        print(
            f"--device: no CUDA device here (torch {torch.__version__}, "
            f"{'CPU-only build' if torch.version.cuda is None else 'CUDA ' + torch.version.cuda}); only the CPU "
            f"({processor_name()}) was measured. bench/gpu_check.py measures the GPU where one is."
        )
        return
    cuda = torch.device("cuda")
    print(f"--device: CPU {processor_name()} (one thread) against {device_name(cuda)}, batch {BATCH}:")
    for method in ("sac", "sage"):
        rng = np.random.default_rng(0)
        variants = {
            "cpu": ours(method, rng),
            "cuda": ours(method, rng, device="cuda"),
            "cuda graph": ours(method, rng, device="cuda", cuda_graph=True),
        }
        median: dict[str, float] = {}
        for name, learner in variants.items():
            sync = torch.cuda.synchronize if name != "cpu" else None
            rate(learner.update, 10, sync)  # warm-up (and the graph's capture)
            median[name] = statistics.median(rate(learner.update, updates, sync) for _ in range(rounds))
        cells = "   ".join(f"{name} {1000.0 / value:7.2f} ms" for name, value in median.items())
        ratios = "   ".join(
            f"{name}/cpu {value / median['cpu']:6.1f}x" for name, value in median.items() if name != "cpu"
        )
        print(f"  {method:5s} {cells}   {ratios}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--updates", type=int, default=200)
    parser.add_argument(
        "--ego",
        action="store_true",
        help="also SAGE-SAC over the ego step (the UGV default's world model: the actor's fear term takes the step's "
        "tensor path, with gradients; sims.ugv.env.ego_motion_layout)",
    )
    parser.add_argument(
        "--clock",
        choices=sorted(CLOCKS),
        default="wall",
        help="what a rate is measured in: wall time (default), or this process's CPU time (a loaded machine)",
    )
    parser.add_argument(
        "--device",
        action="store_true",
        help="also the updates on CUDA, eager and as a CUDA graph, beside the CPU's (says so where there is no CUDA)",
    )
    parser.add_argument("--batch", type=_sizes, help="cost table: these batch sizes (comma-separated)")
    parser.add_argument(
        "--ensemble", type=_sizes, help="cost table: these world-model ensemble sizes (comma-separated)"
    )
    parser.add_argument("--write", type=Path, help="cost table: write it into this markdown file's generated block")
    parser.add_argument(
        "--before",
        metavar="REV",
        help="SAGE-SAC over the ego step + contact with core/sage/{fear,sac,networks}.py at this git commit against "
        "them now",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    from core.device import processor_name

    print(f"processor: {processor_name()}")
    if args.before:
        before_rows(args)
        return
    if args.batch or args.ensemble:
        sizes_table(args)
        return
    if args.write:
        parser.error("--write writes the cost table: give --batch and/or --ensemble")
    rng = np.random.default_rng(0)
    sac, sage, reference = ours("sac", rng), ours("sage", rng), sb3(rng)
    sac_unclipped = ours("sac", rng, max_grad_norm=None)  # SB3's SAC clips no gradients
    assert sage.world_model_ready() and sage.virtual is not None and len(sage.virtual) > 0
    contenders: dict[str, Callable[[], object]] = {
        "our SAC": sac.update,
        "SAGE-SAC": sage.update,
        "our SAC, no clip": sac_unclipped.update,
        "SB3 SAC": lambda: reference.train(gradient_steps=1, batch_size=BATCH),
    }
    if args.ego:
        from sims.ugv.descriptor import contact_floors
        from sims.ugv.env import ego_motion_layout

        ego = ours("sage", rng, world_model=ego_motion_layout())
        assert ego.world_model_ready() and ego.world_model is not None and ego.world_model.ego is not None
        contenders["SAGE-SAC, ego step"] = ego.update
        contact: dict[str, Any] = {"gate.imagined_contact": True, "gate.contact_floors": list(contact_floors())}
        touching = ours("sage", rng, world_model=ego_motion_layout(), **contact)
        assert touching.cfg.gate.imagined_contact and touching.world_model_ready()
        contenders["SAGE-SAC, ego step + contact"] = touching.update
    median = measure(contenders, args.rounds, args.updates, args.clock)
    print(
        f"updates per second (median of {args.rounds} interleaved rounds of {args.updates}, one thread, "
        f"{args.clock} clock):"
    )
    for name, value in median.items():
        print(f"  {name:28s} {value:8.1f} /s   ({1000.0 / value:6.2f} ms per update)")
    print(f"SAGE-SAC update time / our SAC update time: {median['our SAC'] / median['SAGE-SAC']:.2f}x")
    print(
        f"our SAC updates per second / SB3 SAC:       {median['our SAC'] / median['SB3 SAC']:.2f}x"
        f"  (without gradient clipping, as SB3: {median['our SAC, no clip'] / median['SB3 SAC']:.2f}x)"
    )
    if args.ego:
        print(
            "SAGE-SAC over the ego step / SAGE-SAC update time: "
            f"{median['SAGE-SAC'] / median['SAGE-SAC, ego step']:.2f}x"
        )
        print(
            "SAGE-SAC over the ego step / our SAC update time:   "
            f"{median['our SAC'] / median['SAGE-SAC, ego step']:.2f}x  (target <= 2.0x)"
        )
        print(
            "  the same with the gate's imagined contact:        "
            f"{median['our SAC'] / median['SAGE-SAC, ego step + contact']:.2f}x"
        )
    print(f"load average while measuring: {', '.join(f'{x:.2f}' for x in _loadavg())}")
    if args.device:
        device_rows(args.rounds, args.updates)


def measure(contenders: dict[str, Callable[[], object]], rounds: int, updates: int, clock: str) -> dict[str, float]:
    """Median updates per second of each contender over ``rounds`` interleaved rounds (after a warm-up)."""
    rates = measure_rounds(contenders, rounds, updates, clock)
    return {name: statistics.median(values) for name, values in rates.items()}


def measure_rounds(
    contenders: dict[str, Callable[[], object]], rounds: int, updates: int, clock: str
) -> dict[str, list[float]]:
    """Updates per second of each contender in each of ``rounds`` interleaved rounds (after a warm-up)."""
    for fn in contenders.values():  # warm-up
        rate(fn, 20)
    rates: dict[str, list[float]] = {name: [] for name in contenders}
    for _ in range(rounds):
        for name, fn in contenders.items():
            rates[name].append(rate(fn, updates, clock=CLOCKS[clock]))
    return rates


def alternated_rounds(
    contenders: dict[str, Callable[[], object]], rounds: int, updates: int, clock: str
) -> dict[str, list[float]]:
    """Milliseconds per update of each contender in each of ``rounds`` rounds (after a warm-up), the contenders taking
    turns update by update, each update timed alone: a change of the machine's load then falls on all of them alike
    (rounds of consecutive updates per contender, as :func:`measure_rounds`, leave seconds between the updates that
    ``--before`` compares, over which a shared machine's load moves the ratio by several per cent)."""
    read = CLOCKS[clock]
    for fn in contenders.values():  # warm-up
        rate(fn, 20)
    ms: dict[str, list[float]] = {name: [] for name in contenders}
    for _ in range(rounds):
        spent = dict.fromkeys(contenders, 0.0)
        for _ in range(updates):
            for name, fn in contenders.items():
                start = read()
                fn()
                spent[name] += read() - start
        for name, seconds in spent.items():
            ms[name].append(1000.0 * seconds / updates)
    return ms


def before_rows(args: argparse.Namespace) -> None:
    """``--before REV``: SAGE-SAC over the ego step + contact with its update's code at REV and now, on the same
    learner, and our SAC, in interleaved rounds at each batch; per round the now / before time and each side's ratio to
    SAC. The update at REV is the learner's, its class (and its actor's) swapped for those of ``core/sage/sac.py`` (and
    ``core/sage/networks.py``) at REV during the call, that module's ``fear`` being ``core/sage/fear.py``'s at REV."""
    from bench.bench_baselines import module_at
    from sims.ugv.descriptor import contact_floors
    from sims.ugv.env import ego_motion_layout

    old_fear = module_at(args.before, "core/sage/fear.py", "fear_before")
    old_networks = module_at(args.before, "core/sage/networks.py", "networks_before")
    old_sac = module_at(args.before, "core/sage/sac.py", "sac_before")
    vars(old_sac)["fear"] = old_fear.fear  # the name sac_before's code looks up in its globals

    def with_old_code(learner: BaseLearner) -> Callable[[], None]:
        actor = learner.actor  # type: ignore[attr-defined]

        def run() -> None:
            classes = learner.__class__, actor.__class__
            learner.__class__, actor.__class__ = old_sac.SAC, old_networks.Actor
            try:
                learner.update()
            finally:
                learner.__class__, actor.__class__ = classes

        return run

    contact: dict[str, Any] = {"gate.imagined_contact": True, "gate.contact_floors": list(contact_floors())}
    rng = np.random.default_rng(0)
    batches = args.batch or [BATCH]
    contenders: dict[str, Callable[[], object]] = {}
    for batch in batches:
        touching = ours("sage", rng, world_model={**ego_motion_layout(), "members": 5}, batch=batch, **contact)
        contenders[f"sac {batch}"] = ours("sac", rng, batch=batch).update
        contenders[f"before {batch}"] = with_old_code(touching)
        contenders[f"now {batch}"] = touching.update
    ms = alternated_rounds(contenders, args.rounds, args.updates, args.clock)
    print(
        f"SAGE-SAC over the ego step + contact, core/sage/{{fear,sac,networks}}.py at {args.before} (before) and now, "
        f"5 members, one thread, {args.clock} clock, {args.rounds} rounds of {args.updates} updates, the contenders "
        "taking turns update by update (ms per update):"
    )
    for batch in batches:
        sac, before, now = ms[f"sac {batch}"], ms[f"before {batch}"], ms[f"now {batch}"]
        for i in range(args.rounds):
            print(
                f"  batch {batch} round {i + 1}: SAC {sac[i]:6.2f}  before {before[i]:6.2f} ({before[i] / sac[i]:.2f}x)"
                f"  now {now[i]:6.2f} ({now[i] / sac[i]:.2f}x)  now/before {now[i] / before[i]:.3f}"
            )
        ratios = [n / b for n, b in zip(now, before, strict=True)]
        print(
            f"  batch {batch} medians: SAC {statistics.median(sac):.2f}, before {statistics.median(before):.2f} ms "
            f"({statistics.median(b / s for b, s in zip(before, sac, strict=True)):.2f}x SAC), now "
            f"{statistics.median(now):.2f} ms ({statistics.median(n / s for n, s in zip(now, sac, strict=True)):.2f}x "
            f"SAC); now/before median {statistics.median(ratios):.3f}, range {min(ratios):.3f}-{max(ratios):.3f}"
        )
    print(f"load average while measuring: {', '.join(f'{x:.2f}' for x in _loadavg())}")


TABLE_START = "<!-- bench_sac sizes: start (generated by bench/bench_sac.py --write; do not edit) -->"
TABLE_END = "<!-- bench_sac sizes: end -->"


def sizes_table(args: argparse.Namespace) -> None:
    """What larger batches and world-model ensembles cost: ms per update and the ratio to our SAC at the same batch."""
    from core.device import processor_name

    batches, members = args.batch or [BATCH], args.ensemble or [5]
    # each SAGE-SAC column: its world model's layout and the learner's overrides
    layouts: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {"SAGE-SAC": ({}, {})}
    if args.ego:
        from sims.ugv.descriptor import contact_floors
        from sims.ugv.env import ego_motion_layout

        layouts["SAGE-SAC over the ego step"] = (ego_motion_layout(), {})
        contact: dict[str, Any] = {"gate.imagined_contact": True, "gate.contact_floors": list(contact_floors())}
        layouts["SAGE-SAC over the ego step + contact"] = (ego_motion_layout(), contact)
    rng = np.random.default_rng(0)
    contenders: dict[str, Callable[[], object]] = {}
    for batch in batches:
        contenders[f"sac {batch}"] = ours("sac", rng, batch=batch).update
        for n in members:
            for name, (layout, overrides) in layouts.items():
                learner = ours("sage", rng, world_model={**layout, "members": n}, batch=batch, **overrides)
                assert learner.world_model is not None and learner.world_model.members == n
                contenders[f"{name} {batch} {n}"] = learner.update
    rounds = alternated_rounds(contenders, args.rounds, args.updates, args.clock)
    ms = {name: statistics.median(values) for name, values in rounds.items()}
    header = ["batch", "world-model members", "our SAC, ms"]
    for name in layouts:
        header += [f"{name}, ms", f"{name} / SAC"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for batch in batches:
        for n in members:
            sac_ms = ms[f"sac {batch}"]
            row = [str(batch), str(n), f"{sac_ms:.2f}"]
            for name in layouts:
                row += [f"{ms[f'{name} {batch} {n}']:.2f}", f"{ms[f'{name} {batch} {n}'] / sac_ms:.2f}x"]
            lines.append("| " + " | ".join(row) + " |")
    command = "python -m bench.bench_sac " + " ".join(sys.argv[1:])
    load = ", ".join(f"{x:.2f}" for x in _loadavg())
    notes = [
        f"`{command}` at commit {_commit()}, one thread of {processor_name()} (torch {torch.__version__}); median of "
        f"{args.rounds} rounds of {args.updates} updates, the learners taking turns update by update, {args.clock} "
        f"clock; load average {load} at the end; {time.strftime('%Y-%m-%d', time.gmtime())}. SAC has no world model: "
        "its column repeats per ensemble size."
    ]
    table = "\n".join(lines)
    print(table)
    print(notes[0])
    if args.write:
        write_block(args.write, "\n".join([*notes, "", table]))
        print(f"wrote {args.write}")


def write_block(path: Path, block: str, start: str = TABLE_START, end: str = TABLE_END) -> None:
    """Replace the generated block between ``start`` and ``end`` of ``path`` (created with just the block where
    missing)."""
    text = path.read_text(encoding="utf-8") if path.exists() else f"{start}\n{end}\n"
    if start not in text or end not in text:
        raise SystemExit(f"{path} has no generated block ({start} ... {end})")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    path.write_text(f"{head}{start}\n{block}\n{end}{tail}", encoding="utf-8")


def _commit() -> str:
    """The checkout's short commit, marked where tracked files differ from it (the numbers are then not its)."""
    import subprocess

    root = Path(__file__).resolve().parent.parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(["git", "diff", "--quiet", "HEAD"], cwd=root, check=False).returncode != 0
    except (OSError, subprocess.CalledProcessError):
        return "unknown (no git)"
    return f"{commit} with uncommitted changes" if dirty else commit


def _sizes(text: str) -> list[int]:
    try:
        values = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}") from None
    if not values or any(v < 1 for v in values):
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}")
    return values


def _loadavg() -> tuple[float, ...]:
    import os

    return os.getloadavg()


if __name__ == "__main__":
    main()

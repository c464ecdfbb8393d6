"""How fast this host runs the two kinds of work a study is made of: a fixed reference workload, timed.

A study's wall time is its code's cost times the host's speed, and the hosts this project runs on are not alike: the
same trial of the UGV study, code unchanged, took about twice as long on one 2-core "AMD EPYC" host as on another
(docs/notes/study_time.md). A wall time compared across sessions without the host's speed misreads the host as the
code. So every study invocation beyond the smoke budget times this reference before its trials and writes it beside
its wall time (table note, ``summary.json``, the results folder's wall-time log), and ``python -m studies.host_speed``
prints it alone.

The workload, on one thread, deterministic:

- **simulation**: the UGV simulator's scenario 3 (the crossing) driven by its scripted expert for ``sim_steps``
  steps (pymunk, numpy and Python: what every evaluation, demonstration and scripted trial costs);
- **learning**: ``updates`` gradient updates of our SAC at batch 256 (actor and two critics 2 x 128, Adam) on a
  filled buffer (torch on one thread: what the learners' trials cost).

Each is reported as a rate (steps or updates per second of this thread's CPU time) and as seconds; a host twice as
slow halves both. The rates are not a benchmark of the code (``bench/`` is): they are read only against the same
workload's rates on another host or another day.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict, dataclass
from typing import Any

SIM_STEPS = 600
"""Simulation steps of the reference (some 0.7 s of CPU time on the 2026-11-30 host, 811-833 steps/s)."""
UPDATES = 60
"""SAC updates of the reference (some 0.6 s there, 86-102 updates/s)."""
WARMUP_STEPS = 50
"""Untimed simulation steps first (the first episode's steps load caches and cost more)."""
WARMUP_UPDATES = 3
"""Untimed updates first (the first allocates Adam's moments)."""


@dataclass(frozen=True)
class HostSpeed:
    """The reference workload's rates on this host (this thread's CPU time)."""

    sim_steps_per_s: float
    """UGV scenario 3 with the scripted expert driving, steps per CPU second."""
    sac_updates_per_s: float
    """Our SAC at batch 256, updates per CPU second (one torch thread)."""
    seconds: float
    """Wall seconds the whole reference took, building included."""
    processor: str
    """``/proc/cpuinfo``'s model name (hosts of one name differ: that is why the rates are measured)."""
    kernels: str = ""
    """Torch's CPU kernels on this host (``torch.backends.cpu.get_cpu_capability()``: AVX2, AVX512, ...; empty: not
    read). A learner's rows are reproduced only where the float kernels are the same: the UGV study's online learners
    ended 20-32 points apart seed for seed on an AVX-512 host against the AMD ones (docs/notes/study_time.md)."""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def words(self) -> str:
        """``this host's reference speed (`python -m studies.host_speed`, AMD EPYC, torch's CPU kernels AVX2): 1,234
        UGV steps/s with the scripted expert and 56.7 SAC updates/s (batch 256, one thread), CPU time``: what a table's
        timing note says."""
        kernels = f", torch's CPU kernels {self.kernels}" if self.kernels else ""
        return (
            f"this host's reference speed (`python -m studies.host_speed`, {self.processor}{kernels}): "
            f"{self.sim_steps_per_s:,.0f} UGV steps/s with the scripted expert and {self.sac_updates_per_s:.1f} SAC "
            "updates/s (batch 256, one thread), CPU time"
        )


def measure_host_speed(sim_steps: int = SIM_STEPS, updates: int = UPDATES, seed: int = 0) -> HostSpeed:
    """Time the reference workload on this thread (torch's intra-op threads set to one for it, then restored)."""
    import torch

    from core.device import processor_name

    if sim_steps < 1 or updates < 1:
        raise ValueError(f"sim_steps and updates must be >= 1, got {sim_steps} and {updates}")
    started = time.perf_counter()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        sim_rate = sim_steps / _simulate(sim_steps, seed)
        update_rate = updates / _learn(updates, seed)
    finally:
        torch.set_num_threads(threads)
    kernels = torch.backends.cpu.get_cpu_capability()
    return HostSpeed(sim_rate, update_rate, time.perf_counter() - started, processor_name(), kernels)


def _simulate(steps: int, seed: int) -> float:
    """CPU seconds of ``steps`` steps of UGV scenario 3, the scripted expert driving (episodes restart as needed)."""
    from core.experts import ScriptedExpert
    from studies.envs import env_factory

    env = env_factory("ugv")("3")
    expert = ScriptedExpert()
    try:
        obs, _ = env.reset(seed=seed)
        expert.reset()
        episode = 0
        cpu = 0.0
        for step in range(WARMUP_STEPS + steps):  # the first steps load caches: not the host's steady speed
            if step == WARMUP_STEPS:
                cpu = time.process_time()
            action, _ = expert.act(env, obs)
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                episode += 1
                obs, _ = env.reset(seed=seed + episode)
                expert.reset()
        return max(time.process_time() - cpu, 1e-9)
    finally:
        env.close()


def _learn(updates: int, seed: int) -> float:
    """CPU seconds of ``updates`` updates of our SAC at batch 256 on a buffer of random transitions."""
    import numpy as np

    from core.learners import make_learner
    from core.sage.config import for_method

    obs_dim, act_dim = 58, 2  # the UGV's observation and action sizes
    cfg = for_method("sac", hidden=128, batch_size=256, critics=2)
    learner = make_learner(cfg.method, cfg, obs_dim, act_dim, seed=seed, device="cpu")
    rng = np.random.default_rng(seed)
    obs = rng.random((2_001, obs_dim)).astype(np.float32)
    for i in range(2_000):
        learner.buffer.add(
            obs[i], rng.uniform(-1, 1, act_dim).astype(np.float32), float(rng.normal()), obs[i + 1], False
        )
    learner.warm = True
    for _ in range(WARMUP_UPDATES):
        learner.update()
    cpu = time.process_time()
    for _ in range(updates):
        learner.update()
    return max(time.process_time() - cpu, 1e-9)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m studies.host_speed", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sim-steps", type=int, default=SIM_STEPS, help="simulation steps of the reference")
    parser.add_argument("--updates", type=int, default=UPDATES, help="SAC updates of the reference")
    parser.add_argument("--repeat", type=int, default=1, help="measure this many times (the spread reads the noise)")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    for _ in range(args.repeat):
        speed = measure_host_speed(args.sim_steps, args.updates)
        words = speed.words()
        print(f"{words[0].upper()}{words[1:]}; {speed.seconds:.1f} s wall")


if __name__ == "__main__":
    main()

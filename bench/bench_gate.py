"""One gate step on one core: the policy's action, the m = 5 step fear rollout of the N = 5 ensemble, the
curiosity of the executed transition and the threshold update; the gate's compiled kernel
(:class:`core.sage.compiled_gate.CompiledGateKernel`) against its torch kernel (``SageGate(compiled=False)``) and
the same computation with a Python loop over the ensemble members.

Sizes are the UGV's: 58 observations, 2 actions, the default world model (5 x 2 x 64, SiLU) and actor
(2 x 128). The world model is fitted briefly on synthetic transitions (the weights' values do not change
the cost). Both variants are timed in interleaved rounds in the same run; the median of all steps is printed.

    .venv/bin/python bench/bench_gate.py [--steps 3000] [--members 10 25] [--ego] [--novelty]

``--ego`` also times the gate whose world model learns over the UGV's ego step (``WorldModelConfig.ego_*``,
:class:`core.motion.EgoScanStep`: the scan moved geometrically at every imagined step and in the curiosity).
``--novelty`` also times the gate whose curiosity is the state's novelty (``gate.curiosity_signal=novelty``,
:mod:`core.sage.novelty`) against a full reference set (2,048 states of 58 observations and their motion input).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F

from core.sage.calibration import calibrate
from core.sage.config import GateConfig, WorldModelConfig
from core.sage.fear import step_scales
from core.sage.gate import SageGate
from core.sage.learner import ActorPolicy
from core.sage.networks import Actor
from core.sage.novelty import HELD_OUT_STATES, REFERENCE_STATES
from core.sage.world_model import EnsembleWorldModel

OBS_DIM, ACT_DIM = 58, 2
TARGET_MS = 0.5
EGO_TARGET_MS = 0.3
"""Issue 63's target for the gate over the ego step."""


class LoopGate:
    """The gate's fear and curiosity with one matrix product per member and layer (the slow path)."""

    def __init__(self, model: EnsembleWorldModel, actor: Actor, cfg: GateConfig) -> None:
        fm = model.folded()
        self.fm, self.actor, self.cfg = fm, actor, cfg
        self.members = [
            (
                [(w[n].contiguous(), b[n, 0].contiguous()) for w, b in fm.hidden],
                fm.out_weight[n].contiguous(),
                fm.out_bias[n, 0].contiguous(),
            )
            for n in range(fm.members)
        ]
        self.divisor = 2.0 * step_scales(fm.sigma_scale, cfg.horizon)[:, 0]

    def member_forward(self, n: int, x: torch.Tensor) -> torch.Tensor:
        hidden, ow, ob = self.members[n]
        for w, b in hidden:
            x = F.silu(torch.addmm(b, x, w))
        return torch.addmm(ob, x, ow)

    def fear(self, obs: torch.Tensor, action: torch.Tensor, motion: torch.Tensor) -> float:
        """F^m as :func:`core.sage.fear.fear` computes it (motion input, ĉ and σ̂ from the members' violation
        probabilities, the maximum over the horizon), one member at a time."""
        fm, d, members = self.fm, self.fm.obs_dim, range(self.fm.members)
        states, actions, motions = [obs for _ in members], [action for _ in members], [motion for _ in members]
        costs, sigmas = [], []
        for k in range(self.cfg.horizon):
            outs = [self.member_forward(n, torch.cat([states[n], actions[n], motions[n]], -1)) for n in members]
            motions = [torch.lerp(motions[n], outs[n][:, :d], 1.0 / fm.motion_lag) for n in members]
            states = [states[n] + outs[n][:, :d] for n in members]
            probability = torch.sigmoid(torch.stack([o[0, d] for o in outs]))
            sigma_raw = (probability - probability.mean()).square().mean().clamp_min(1e-12).sqrt()
            sigmas.append(torch.tanh(sigma_raw / self.divisor[k]))
            costs.append(probability.mean())
            if k + 1 < self.cfg.horizon:
                actions = [self.actor.deterministic(s) for s in states]
        c, s = float(torch.stack(costs).max()), float(torch.stack(sigmas).max())
        return self.cfg.beta * c + (1 - self.cfg.beta) * s

    def curiosity(self, obs: torch.Tensor, action: torch.Tensor, next_obs: torch.Tensor, motion: torch.Tensor) -> float:
        d = self.fm.obs_dim
        x = torch.cat([obs, action, motion], -1)
        delta = torch.stack([self.member_forward(n, x)[:, :d] for n in range(self.fm.members)]).mean(0)
        return float(((obs + delta - next_obs) * self.fm.inv_obs_std).norm())


def setup(members: int = 5, ego: bool = False) -> tuple[EnsembleWorldModel, Actor, np.ndarray, np.ndarray]:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    obs = rng.random((2000, OBS_DIM)).astype(np.float32)
    act = rng.uniform(-1, 1, (2000, ACT_DIM)).astype(np.float32)
    nxt = (obs + 0.01 * rng.standard_normal(obs.shape)).astype(np.float32)
    layout: dict[str, float] = {}
    if ego:
        from sims.ugv.env import ego_motion_layout

        layout = ego_motion_layout()
    model = EnsembleWorldModel(OBS_DIM, ACT_DIM, WorldModelConfig(members=members, max_updates_per_fit=100, **layout))
    model.fit(obs, act, nxt, rng.random(2000).astype(np.float32), rng)
    actor = Actor(OBS_DIM, ACT_DIM, 128, 2, -torch.ones(ACT_DIM), torch.ones(ACT_DIM))
    return model, actor, obs, nxt


def novelty_gate(actor: Actor) -> SageGate:
    """A gate whose curiosity is state novelty, its model calibrated on enough states for a full reference set."""
    model = setup()[0]
    rng = np.random.default_rng(1)
    states = torch.from_numpy(rng.random((REFERENCE_STATES + HELD_OUT_STATES, OBS_DIM)).astype(np.float32))
    cfg = GateConfig(curiosity_signal="novelty", curiosity_reference="fitted")
    calibrate(model, actor.deterministic, states, cfg.horizon, cfg=cfg, motion=0.01 * torch.randn_like(states))
    return SageGate(model, actor, cfg)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument(
        "--members",
        type=int,
        nargs="*",
        default=[],
        help="also time the batched gate with ensembles of these sizes (a merged ensemble, sage gate merge)",
    )
    parser.add_argument("--ego", action="store_true", help="also time the gate over the UGV's ego step")
    parser.add_argument("--novelty", action="store_true", help="also time the gate whose curiosity is state novelty")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model, actor, observations, next_observations = setup()
    cfg = GateConfig()
    gate = SageGate(model, actor, cfg)
    policy = ActorPolicy(actor)
    loop = LoopGate(model, actor, cfg)
    larger: dict[str, SageGate] = {"torch kernel": SageGate(model, actor, cfg, compiled=False)}
    larger.update({f"batched, N={n}": SageGate(setup(n)[0], actor, cfg) for n in args.members})
    if args.ego:
        ego_model = setup(ego=True)[0]
        larger["batched, ego step"] = SageGate(ego_model, actor, cfg)
        larger["torch kernel, ego step"] = SageGate(ego_model, actor, cfg, compiled=False)
    if args.novelty:
        larger["novelty curiosity"] = novelty_gate(actor)

    def other_step(name: str) -> Callable[[int], float]:
        def step(i: int) -> float:
            obs = observations[i % len(observations)]
            action = policy.act(obs, deterministic=True)
            decision = larger[name].decide(obs, action)
            larger[name].observe(obs, action, next_observations[i % len(observations)])
            return decision.fear

        return step

    def batched_step(i: int) -> float:
        obs = observations[i % len(observations)]
        action = policy.act(obs, deterministic=True)
        decision = gate.decide(obs, action)
        gate.observe(obs, action, next_observations[i % len(observations)])
        return decision.fear

    def loop_step(i: int) -> float:
        obs = observations[i % len(observations)]
        action = policy.act(obs, deterministic=True)
        with torch.inference_mode():
            o, a = torch.from_numpy(obs).view(1, -1), torch.from_numpy(action).view(1, -1)
            # the gate's motion input: the change since the observation it saw last (none at the first)
            m = torch.zeros_like(o) if i == 0 else o - torch.from_numpy(observations[(i - 1) % len(observations)])
            value = loop.fear(o, a, m)
            loop.curiosity(o, a, torch.from_numpy(next_observations[i % len(observations)]).view(1, -1), m)
        return value

    for i in range(20):  # same numbers, and warm caches
        assert abs(batched_step(i) - loop_step(i)) < 1e-4
    steps: dict[str, Callable[[int], float]] = {"batched (SageGate)": batched_step, "loop over members": loop_step}
    steps.update({name: other_step(name) for name in larger})
    names = tuple(steps)
    wall: dict[str, list[float]] = {name: [] for name in names}
    cpu: dict[str, list[float]] = {name: [] for name in names}
    per_round = max(1, args.steps // args.rounds)
    for r in range(args.rounds):
        for name, fn in steps.items():
            for i in range(r * per_round, (r + 1) * per_round):
                start, start_cpu = time.perf_counter(), time.thread_time()
                fn(i)
                cpu[name].append(time.thread_time() - start_cpu)
                wall[name].append(time.perf_counter() - start)
    print(
        f"gate step = policy + m={cfg.horizon} rollout of N={model.members} members + curiosity + threshold, "
        f"one thread, {len(wall[names[0]])} steps each (ms; CPU = this thread's CPU time, wall = elapsed)"
    )
    for name in names:
        print(
            f"  {name:20s} CPU median {statistics.median(cpu[name]) * 1e3:.3f}   "
            f"wall median {statistics.median(wall[name]) * 1e3:.3f}   wall p90 {np.quantile(wall[name], 0.9) * 1e3:.3f}"
        )
    batched_cpu, batched_wall = statistics.median(cpu[names[0]]) * 1e3, statistics.median(wall[names[0]]) * 1e3
    print(f"loop / batched (CPU medians): {statistics.median(cpu[names[1]]) / statistics.median(cpu[names[0]]):.2f}x")
    ratio = statistics.median(cpu["torch kernel"]) / statistics.median(cpu[names[0]])
    print(f"torch kernel / compiled kernel (CPU medians): {ratio:.2f}x")
    for n in args.members:
        ratio = statistics.median(cpu[f"batched, N={n}"]) / statistics.median(cpu[names[0]])
        print(f"batched N={n} / N={model.members} (CPU medians): {ratio:.2f}x")
    if args.novelty:
        added = (statistics.median(cpu["novelty curiosity"]) - statistics.median(cpu[names[0]])) * 1e3
        print(f"novelty curiosity / the paper's (CPU medians): {added:+.3f} ms a step")
    if args.ego:
        ratio = statistics.median(cpu["batched, ego step"]) / statistics.median(cpu[names[0]])
        print(f"ego step / without (CPU medians): {ratio:.2f}x")
        ratio = statistics.median(cpu["torch kernel, ego step"]) / statistics.median(cpu["batched, ego step"])
        print(f"over the ego step, torch kernel / compiled kernel (CPU medians): {ratio:.2f}x")
        ego_cpu = statistics.median(cpu["batched, ego step"]) * 1e3
        verdict = "OK" if ego_cpu <= EGO_TARGET_MS else "ABOVE TARGET"
        print(
            f"target, the gate over the ego step: median <= {EGO_TARGET_MS} ms on one core: {ego_cpu:.3f} ms {verdict}"
        )
    verdict = "OK" if batched_cpu <= TARGET_MS else "ABOVE TARGET"
    print(
        f"target: median <= {TARGET_MS} ms on one core: CPU {batched_cpu:.3f} ms {verdict}; wall {batched_wall:.3f} ms"
    )
    from core.device import processor_name

    print(f"processor: {processor_name()}")
    load = os.getloadavg()
    print(
        f"load average while measuring: {', '.join(f'{x:.2f}' for x in load)} on {os.cpu_count()} cores"
        + ("  (busy machine: wall times include waiting for a core)" if load[0] > (os.cpu_count() or 1) * 0.75 else "")
    )


if __name__ == "__main__":
    main()

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

``--policy policies/ugv-default`` times instead the gate exactly as that policy deploys it: the checkpoint and its
gate settings loaded as the live server and ``sage gate evaluate`` load them (:func:`core.agents.load_agent`,
``make_gate()``; for the UGV default the mover model, imagined contact over 10 steps and its τ scale). First it
records ``--record`` real transitions (the policy driving with its gate and no expert, on ``--scenario``: the
UGV's movers field by default), then replays the recording through the deployed gate (compiled: its rollout, mover
velocities and movers' contact test) and the same gate uncompiled (``SageGate(compiled=False)``: the torch kernel and
numpy's mover velocities), and for a UGV policy the synthetic gate of ``--ego`` (its idle time known: it reads the
machine's load), in interleaved rounds (each round the whole recording through each in turn; an
episode's first step resets the gate, as the loop does), one thread. A step is the policy's deterministic action,
``decide`` and ``observe``. A separate instrumented replay splits the deployed step into its parts (the mover
velocities, the rollout, the movers' contact, the rest of ``decide``, ``observe``, the policy).
``--write docs/speed.md`` writes that report into the document's generated block.

    .venv/bin/python -m bench.bench_gate --policy policies/ugv-default [--record 400] [--write docs/speed.md]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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
    layout: dict[str, Any] = {}
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


POLICY_START = "<!-- bench_gate policy: start (generated by bench/bench_gate.py --policy ... --write; do not edit) -->"
POLICY_END = "<!-- bench_gate policy: end -->"
DEPLOYED, TORCH_KERNEL = "deployed (compiled)", "uncompiled (torch kernel, numpy movers)"
SYNTHETIC = "synthetic (`--ego`'s gate)"
"""The README's synthetic gate over the ego step (a briefly fitted model, the paper's 5-step fear, no contact or mover
model) over the same recorded steps: its idle figure is known, so its time in the same run reads the machine's load."""


@dataclass(frozen=True)
class Transition:
    """One recorded step of the loop: what the gate saw, what it decided on and what was executed."""

    first: bool
    """The first step of an episode (the loop resets the gate before it)."""
    obs: np.ndarray
    a_rl: np.ndarray
    action: np.ndarray
    next_obs: np.ndarray
    fear: float
    """The deployed gate's fear at this step while recording."""


def default_scenario(sim: str) -> str:
    """The scenario a policy's gate is timed on: the UGV's field of movers (the mover model's work), else the
    simulator's default."""
    import sims

    return "sims/ugv/scenarios/movers.yaml" if sim == "ugv" else sims.descriptor(sim).default_scenario


def record(agent: Any, scenario: str, steps: int, seed: int = 0) -> list[Transition]:
    """``steps`` transitions of ``agent``'s policy driving with its deployed gate and no expert (as
    ``sage gate evaluate`` drives it) on ``scenario``, episodes seeded from ``seed``."""
    import sims
    from core.loop import Runner

    env = sims.make(agent.meta.sim, scenario)
    runner = Runner(env, agent.policy, agent.make_gate(), None, seed=seed, deterministic=True)
    out: list[Transition] = []
    try:
        while len(out) < steps:
            step = runner.step()
            if step is None:  # the simulator failed: the episode ended with the error, the next one starts
                continue
            copy = (np.array(step.obs), np.array(step.a_rl), np.array(step.action), np.array(step.next_obs))
            out.append(Transition(step.t == 0, *copy, float(step.fear)))
    finally:
        env.close()
    return out


def policy_gates(agent: Any) -> dict[str, Any]:
    """The policy's deployed gate and the same gate uncompiled (fresh, from the checkpoint's settings)."""
    deployed, torch_kernel = agent.make_gate(), agent.make_gate()
    torch_kernel.compiled = False  # read when its kernel is first built and at every mover velocity
    return {DEPLOYED: deployed, TORCH_KERNEL: torch_kernel}


def replay(policy: Any, gate: Any, recording: list[Transition], clocks: list[list[float]] | None = None) -> list[float]:
    """The recording through ``policy`` and ``gate`` as the loop steps them; each step's fear. ``clocks``: where given,
    [CPU, wall] lists that receive each step's seconds (the policy's action, ``decide`` and ``observe``)."""
    fears = []
    for i, step in enumerate(recording):
        if step.first or i == 0:
            gate.reset()
        start, start_cpu = time.perf_counter(), time.thread_time()
        action = policy.act(step.obs, deterministic=True)
        decision = gate.decide(step.obs, action)
        gate.observe(step.obs, step.action, step.next_obs)
        if clocks is not None:
            clocks[0].append(time.thread_time() - start_cpu)
            clocks[1].append(time.perf_counter() - start)
        fears.append(decision.fear)
    return fears


@contextmanager
def _timed(owner: Any, name: str, totals: dict[str, float], key: str) -> Iterator[None]:
    """Add the CPU time of every call of ``owner.name`` to ``totals[key]`` while inside (restored after)."""
    original = getattr(owner, name)

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.thread_time()
        try:
            return original(*args, **kwargs)
        finally:
            totals[key] = totals.get(key, 0.0) + time.thread_time() - start

    setattr(owner, name, wrapper)
    try:
        yield
    finally:
        if isinstance(owner, type) or hasattr(owner, "__file__"):
            setattr(owner, name, original)
        else:
            delattr(owner, name)  # an instance's own attribute: its class's method shows again


def profile_parts(agent: Any, recording: list[Transition], passes: int = 2) -> dict[str, float]:
    """Mean CPU ms per step of each part of the deployed gate's step, over ``passes`` instrumented replays (after a
    warm one): the policy, ``decide`` and in it the mover velocities, the rollout (the compiled call), the movers'
    contact, and ``observe``. The instruments' own cost falls on the enclosing part."""
    import core.sage.compiled_gate as compiled_gate

    gate, policy = agent.make_gate(), agent.policy
    replay(policy, gate, recording)
    kernel = gate.kernel()
    totals: dict[str, float] = {}
    with (
        _timed(policy, "act", totals, "policy"),
        _timed(gate, "decide", totals, "decide"),
        _timed(gate, "observe", totals, "observe"),
        _timed(gate, "_mover_velocity", totals, "mover velocities"),
        _timed(compiled_gate, "gate_rollout", totals, "rollout"),
    ):
        movers = hasattr(kernel, "_with_movers")
        if movers:
            with _timed(kernel, "_with_movers", totals, "movers' contact"):
                for _ in range(passes):
                    replay(policy, gate, recording)
        else:
            for _ in range(passes):
                replay(policy, gate, recording)
    steps = passes * len(recording)
    ms = {key: value / steps * 1e3 for key, value in totals.items()}
    inside = sum(ms.get(key, 0.0) for key in ("mover velocities", "rollout", "movers' contact"))
    ms["rest of decide"] = ms.get("decide", 0.0) - inside
    return ms


def policy_report(
    path: str, scenario: str, recording: list[Transition], rounds: int, load_start: tuple[float, ...], command: str
) -> tuple[str, dict[str, float]]:
    """Time the policy's gates over ``recording``; the report (markdown, naming ``command``) and the medians (CPU
    ms)."""
    from bench.bench_sac import _commit
    from core.agents import load_agent
    from core.device import processor_name

    agent = load_agent(path)
    gates = policy_gates(agent)
    policies = {name: agent.policy for name in gates}
    if agent.meta.obs_dim == OBS_DIM and agent.meta.act_dim == ACT_DIM:  # the synthetic gate's sizes: the UGV's
        ego_model, actor = setup(ego=True)[:2]
        gates[SYNTHETIC], policies[SYNTHETIC] = SageGate(ego_model, actor, GateConfig()), ActorPolicy(actor)
    fears = {name: replay(policies[name], gate, recording) for name, gate in gates.items()}  # warm: compiles
    recorded = np.array([step.fear for step in recording])
    same = float(np.nanmax(np.abs(np.array(fears[DEPLOYED]) - recorded)))
    gap = np.abs(np.array(fears[TORCH_KERNEL]) - np.array(fears[DEPLOYED]))
    cpu: dict[str, list[float]] = {name: [] for name in gates}
    wall: dict[str, list[float]] = {name: [] for name in gates}
    round_medians: dict[str, list[float]] = {name: [] for name in gates}
    for _ in range(rounds):
        for name, gate in gates.items():
            clocks: list[list[float]] = [[], []]
            replay(policies[name], gate, recording, clocks)
            cpu[name] += clocks[0]
            wall[name] += clocks[1]
            round_medians[name].append(statistics.median(clocks[0]) * 1e3)
    parts = profile_parts(agent, recording)
    load_end = os.getloadavg()
    med = {name: statistics.median(values) * 1e3 for name, values in cpu.items()}
    cfg = gates[DEPLOYED].cfg
    episodes = sum(step.first for step in recording)
    lines = [
        f"`{command}` at commit {_commit()}, one thread of "
        f"{processor_name()} (torch {torch.__version__}), {time.strftime('%Y-%m-%d', time.gmtime())}; load average "
        f"{', '.join(f'{x:.2f}' for x in load_start)} at the start, {', '.join(f'{x:.2f}' for x in load_end)} at the "
        f"end, on {os.cpu_count()} cores.",
        "",
        f"The gate of `{path}` as it deploys it (horizon {cfg.horizon}, contact horizon {cfg.contact_horizon}, mover "
        f"model {cfg.mover_model}, τ scale {cfg.tau_scale}, curiosity {cfg.curiosity_signal}), over "
        f"{len(recording)} recorded steps ({episodes} episode starts) of the policy driving with it and no expert "
        f"on `{scenario}`, seed 0; {rounds} interleaved rounds of the whole recording each; a step is the policy's "
        "action, `decide` and `observe`, timed in this thread's CPU time. The replayed deployed gate's fear differs "
        f"from the recorded by at most {same:.1e}; the uncompiled gate's from the compiled one's by at most "
        f"{float(gap.max()):.1e} (over 1e-4 at {int((gap > 1e-4).sum())} of {len(gap)} steps).",
        "",
        "| gate | step, median ms (CPU) | round medians, ms | p90, ms | wall median, ms |",
        "|---|---|---|---|---|",
    ]
    for name in gates:
        lines.append(
            f"| {name} | {med[name]:.3f} | {min(round_medians[name]):.3f}-{max(round_medians[name]):.3f} | "
            f"{np.quantile(cpu[name], 0.9) * 1e3:.3f} | {statistics.median(wall[name]) * 1e3:.3f} |"
        )
    verdict = "met" if med[DEPLOYED] <= EGO_TARGET_MS else "not met"
    lines += [
        "",
        f"Uncompiled / compiled: {med[TORCH_KERNEL] / med[DEPLOYED]:.2f}x. Issue 63's target, the UGV gate "
        f"step over the ego step at most {EGO_TARGET_MS} ms on one core: {med[DEPLOYED]:.3f} ms, {verdict}.",
        *(
            [
                "",
                f"Deployed / synthetic: {med[DEPLOYED] / med[SYNTHETIC]:.2f}x. The synthetic gate (`bench_gate.py "
                "--ego`: the paper's 5-step fear over the ego step, no contact or mover model, a briefly fitted model)"
                " over the same steps reads the machine's load: the README's figure for it was measured idle.",
            ]
            if SYNTHETIC in med
            else []
        ),
        "",
        "The deployed step's parts (a separate instrumented replay of the recording, twice; mean CPU ms per step):",
        "",
        "| part | mean ms per step | share of the step |",
        "|---|---|---|",
    ]
    total = parts.get("policy", 0.0) + parts.get("decide", 0.0) + parts.get("observe", 0.0)
    for key in ("policy", "mover velocities", "rollout", "movers' contact", "rest of decide", "observe"):
        if key in parts:
            lines.append(f"| {key} | {parts[key]:.3f} | {parts[key] / total:.0%} |")
    lines.append(f"| the whole step (mean) | {total:.3f} | 100% |")
    return "\n".join(lines), med


def policy_main(args: argparse.Namespace) -> None:
    from core.agents import load_agent

    torch.set_num_threads(1)
    load_start = os.getloadavg()
    agent = load_agent(args.policy)
    scenario = args.scenario or default_scenario(agent.meta.sim)
    recording = record(agent, scenario, args.record)
    command = "python -m bench.bench_gate " + " ".join(sys.argv[1:])
    report, _ = policy_report(args.policy, scenario, recording, args.rounds, load_start, command)
    print(report)
    if args.write:
        from bench.bench_sac import write_block

        write_block(args.write, report, POLICY_START, POLICY_END)
        print(f"wrote {args.write}")


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
    parser.add_argument(
        "--policy", help="time instead the gate as this policy (a run folder or checkpoint) deploys it, on real steps"
    )
    parser.add_argument("--scenario", help="--policy: the scenario recorded (default: the UGV's movers field)")
    parser.add_argument("--record", type=int, default=400, help="--policy: the steps recorded and replayed")
    parser.add_argument("--write", type=Path, help="--policy: write the report into this markdown file's block")
    args = parser.parse_args()
    if args.policy:
        policy_main(args)
        return
    if args.write:
        parser.error("--write writes the --policy report: give --policy")
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

"""Headless training and evaluation on the one step loop (:class:`core.loop.Runner`).

Training puts the learner in a ``Runner`` as its policy and appends ``learner.observe`` to the step
listeners: the loop feeds the replay buffer, and the learner refits its world model and runs its gradient
updates from there. SAGE and HG-DAgger runs get the SAGE gate and the scripted expert
(:class:`core.experts.ScriptedExpert`); FNI-RL gets the gate without an expert (its fear and curiosity are
recorded, nobody takes over); SAC and TD3 get neither. Demonstrations (``demo_episodes``) are the same loop
with a gate that always fires, so the expert drives and both actions are recorded as intervention samples.

Several scenarios train one learner in turn (one ``Runner`` per scenario env, episodes round-robin).
Nothing here imports a simulator: the caller passes ``make_env(scenario) -> gym.Env``. Study protocols
(a route switch, closed-loop adversarial scenarios) hook in with ``before_episode`` callbacks, which see the
episode index and the ``Runner`` about to run it (its env, its policy, its expert). ``RunConfig.expert`` makes
another run's policy the expert (:class:`core.experts.PolicyExpert`) in place of the simulator's scripted one.

A run folder holds ``config.json`` ({"run", "agent", "meta"}), ``metrics.jsonl`` (one row per episode: the
loop's :class:`~core.loop.EpisodeSummary` row, the simulator's metrics and the learner's statistics),
``checkpoint.pt`` and ``checkpoints/episode_NNNNN.pt`` (see :mod:`core.agents`), and with a world model
``calibration.npz``, the states its last fit set κ and the τ bounds on
(:class:`core.sage.calibration.CalibrationSample`).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from core.agents import (
    CHECKPOINT_DIR,
    FINAL_CHECKPOINT,
    AgentMeta,
    action_bounds,
    fear_shape_moved,
    load_agent,
    load_checkpoint,
    meta_of,
    save_checkpoint,
)
from core.datasets import records
from core.experts import CostSupervisor, PolicyExpert, ScriptedExpert
from core.learners import make_learner
from core.loop import EpisodeSummary, Expert, Gate, NoGate, Policy, Runner, StepRecord
from core.planners import PlannerExpert, PlannerFactory, checked_entry, is_planner
from core.sage.calibration import CALIBRATION_FILE
from core.sage.captured import require_cuda
from core.sage.config import AgentConfig, to_dict, world_model_refit
from core.sage.gate import AlwaysGate
from core.sage.learner import BaseLearner

EnvFactory = Callable[[str], gym.Env[Any, Any]]
"""Builds the env of one scenario (the CLI passes ``lambda s: sims.make(sim, scenario=s)``)."""
EpisodeHook = Callable[[int, Runner], None]
"""Called before each training episode with its 0-based index and the Runner about to run it: a protocol
changes the env's next scenario there (``runner.set_next_reset_options``: gymnasium reset options), points the
env at the current policy (``runner.policy``) or swaps the expert (``runner.set_expert``). A hook object may also
define ``start_interaction(steps_done, train_steps)``, called once after the demonstrations, and
``episode_cap() -> int | None``, read after it is called: the most steps the coming episode may take (a phase
that ends at a step count cuts its last episode there)."""

DEMO_SEED_OFFSET = 500_000
EVAL_SEED_OFFSET = 1_000_000
SCENARIO_SEED_STRIDE = 10_000_000


@dataclass
class RunConfig:
    """The training run around the learner (the learner's own settings are :class:`AgentConfig`)."""

    sim: str
    """Simulator short name (``ugv``, ``highway``, ``sumo``): recorded in the checkpoints."""
    scenarios: list[str]
    """Scenarios trained on, round-robin, one episode each in turn (passed through to the simulator)."""
    episodes: int | None
    """Training episodes in total (demonstrations not counted); None: ``train_steps`` alone bounds the run."""
    seed: int = 0
    """Seeds torch, numpy and the episodes (episode i of scenario j uses seed + j·10^7 + i)."""
    init: str | None = None
    """Run folder or checkpoint to warm-start from (the parts that fit: actor, critics, world model, ...)."""
    demo_episodes: int = 0
    """Expert-driven episodes recorded as intervention samples before training (then cloned: see pretrain)."""
    demo_steps: int | None = None
    """Most environment steps the demonstrations may take, the last one cut there (None: up to ``train_steps``),
    so that a small step budget still leaves steps to interact in."""
    demo_noise: float = 0.0
    """Std of Gaussian noise on the expert's demonstrated actions (DART-style: the demonstrations then visit
    the states a slightly imperfect clone drifts into, and the zero-mean noise averages out in the regression)."""
    checkpoint_every: int = 25
    """Episodes between checkpoint versions (0: only the final checkpoint)."""
    checkpoint_dtype: str = "float32"
    """``float16`` halves the checkpoint files (used for the committed default policy)."""
    max_episode_steps: int | None = None
    """Cut episodes at this many steps (None: the simulator's own time limit)."""
    expert: str | None = None
    """Run folder or checkpoint whose deterministic policy is the expert (takeovers and demonstrations), or a
    planner's name (:mod:`core.planners`: ``scripted``, ...); None: the simulator's scripted expert."""
    demo_expert: str | None = None
    """The demonstrations' expert, by the same names as ``expert`` (None: ``expert``): demonstrations of one
    behaviour (a UGV expert blind to movers, whose runs into them teach the world model what a collision is) while
    the takeovers of the same run come from another (the expert that yields)."""
    train_steps: int | None = None
    """Environment steps in total, demonstrations included: the studies' budget, the same for every method
    (an episode that would pass it is cut there). None: ``episodes`` alone bounds the run."""
    datasets: list[str] = field(default_factory=list)
    """Offline data loaded into the buffer after the demonstrations and before pretraining (:mod:`core.datasets`:
    recorded session files, ``minari:<id>``); not counted in ``train_steps`` (no environment step is taken)."""
    env: dict[str, Any] = field(default_factory=dict)
    """Simulator config overrides that every env of the run was built with (``--set env.KEY=VALUE``), recorded in
    config.json; the caller's ``make_env`` applies them."""
    world_model_only: bool = False
    """Refit only the world model of ``init`` (:func:`core.sage.config.world_model_refit`): the policy drives and
    nothing else learns; checkpoints keep the learner config given (the policy's own schedule)."""
    device: str = "auto"
    """Where the learner's updates run (``auto``: CUDA when torch sees one, else the CPU; ``cpu``; ``cuda``):
    :func:`core.device.resolve_device`. The loop's policy, the gate and the world model's fit stay on the CPU."""
    refit_gated_share: float = 0.0
    """A world-model-only refit: the share of its episodes (of each scenario, spread evenly) driven as the policy
    is deployed, its gate handing control to the expert; the others, the policy alone. The deployed loop visits
    states the policy alone never reaches, where the expert hands control back (a car stopped at a stop line on
    red): a model fitted on the policy alone has never seen what the policy does there."""


@dataclass
class TrainResult:
    rows: list[dict[str, Any]]
    learner: BaseLearner
    out: Path | None
    demo_rows: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0


def _dims(env: gym.Env[Any, Any]) -> tuple[int, int, np.ndarray, np.ndarray]:
    obs_shape = getattr(env.observation_space, "shape", None)
    if not obs_shape or len(obs_shape) != 1:
        raise TypeError(f"observation space {env.observation_space} is not a flat Box")
    low, high = action_bounds(env.action_space)
    return int(obs_shape[0]), len(low), low, high


def _tag(row: dict[str, Any], **extra: Any) -> dict[str, Any]:
    row = dict(row)
    row.update(extra)
    return row


class NoisyExpert:
    """An expert whose actions get Gaussian noise (clipped to the action bounds), for demonstrations."""

    def __init__(self, expert: Expert, std: float, low: np.ndarray, high: np.ndarray, seed: int) -> None:
        self.expert, self.std, self.low, self.high = expert, std, low, high
        self.rng = np.random.default_rng(seed + DEMO_SEED_OFFSET)

    def reset(self) -> None:
        self.expert.reset()

    def wants_control(self) -> bool:
        return self.expert.wants_control()

    def act(self, env: gym.Env[Any, Any], obs: np.ndarray) -> tuple[np.ndarray, Any]:
        action, actor = self.expert.act(env, obs)
        noisy = np.asarray(action, np.float32) + self.rng.normal(0.0, self.std, np.shape(action)).astype(np.float32)
        return np.clip(noisy, self.low, self.high), actor


class Trainer:
    """One training run: build envs and learner, (demonstrate,) train, checkpoint. See the module docstring."""

    def __init__(
        self,
        run: RunConfig,
        agent: AgentConfig,
        make_env: EnvFactory,
        out: Path | None = None,
        progress: bool = True,
        before_episode: Sequence[EpisodeHook] = (),
    ) -> None:
        if (run.episodes is not None and run.episodes < 0) or run.demo_episodes < 0:
            raise ValueError("episodes and demo_episodes must be >= 0")
        if run.demo_steps is not None and run.demo_steps < 1:
            raise ValueError(f"demo_steps must be >= 1, got {run.demo_steps}")
        if run.train_steps is not None and run.train_steps < 1:
            raise ValueError(f"train_steps must be >= 1, got {run.train_steps}")
        if run.episodes is None and run.train_steps is None:
            raise ValueError("bound the run: give episodes, train_steps or both")
        if not run.scenarios:
            raise ValueError("at least one scenario is needed")
        self.saved_cfg = agent
        """The learner config the checkpoints and config.json record (a world-model-only refit runs another)."""
        if not 0.0 <= run.refit_gated_share <= 1.0:
            raise ValueError(f"refit_gated_share must be in [0, 1], got {run.refit_gated_share}")
        if run.refit_gated_share > 0 and not run.world_model_only:
            raise ValueError("refit_gated_share is for a world-model-only refit (--world-model-only)")
        if run.world_model_only:
            if not run.init:
                raise ValueError("--world-model-only refits the world model of a trained policy: give --init")
            agent = world_model_refit(agent)
            # the checkpoints carry the fitted world model, so their config must say it has one (a policy preset
            # without it made fine-tuning rebuild the learner without a world model: no gate after the first cycle)
            self.saved_cfg = copy.deepcopy(self.saved_cfg)
            self.saved_cfg.world_model = True
        self.run, self.agent_cfg, self.out, self.progress = run, agent, out, progress
        self.before_episode: list[EpisodeHook] = list(before_episode)
        torch.manual_seed(run.seed)
        self.envs = {s: make_env(s) for s in run.scenarios}
        first = self.envs[run.scenarios[0]]
        self.obs_dim, self.act_dim, self.low, self.high = _dims(first)
        for s, env in self.envs.items():
            if _dims(env)[:2] != (self.obs_dim, self.act_dim):
                raise ValueError(f"scenario {s} has other observation/action sizes than {run.scenarios[0]}")
        self.learner = make_learner(
            agent.method, agent, self.obs_dim, self.act_dim, self.low, self.high, run.seed, device=run.device
        )
        if agent.cuda_graph:
            require_cuda(self.learner.device)  # one clear line before any episode, not at the first update
        if run.demo_noise > 0 and self.learner.encodes_actions:
            raise ValueError("--demo-noise perturbs continuous actions; this learner's actions are discrete")
        self.expert = self._make_expert(run.expert)
        self.demo_expert = self.expert if run.demo_expert is None else self._make_expert(run.demo_expert)
        self.init_parts: list[str] = []
        if run.init:
            self.init_parts = self._warm_start(run.init)
        self.rows: list[dict[str, Any]] = []
        self.episodes_done = 0
        self.steps_done = 0
        """Environment steps taken so far, demonstrations included (what ``train_steps`` bounds)."""

    def _warm_start(self, path: str) -> list[str]:
        payload = load_checkpoint(path)
        meta = meta_of(payload)
        if (meta.obs_dim, meta.act_dim) != (self.obs_dim, self.act_dim):
            raise ValueError(
                f"--init {path}: its policy takes {meta.obs_dim} observations / {meta.act_dim} actions, "
                f"this simulator has {self.obs_dim} / {self.act_dim}"
            )
        run = self.run
        if run.world_model_only and not (run.episodes or run.demo_episodes or run.train_steps):
            # no step, so no fit: the init's τ bounds are written as they are, measured on the init's fear
            own = payload["agent_config"].get("gate", {})
            gate = self.saved_cfg.gate
            moved = fear_shape_moved(own, gate)
            if moved:
                raise ValueError(
                    f"--init {path}: gate {', '.join(f'{n}={getattr(gate, n)}' for n in moved)} changes fear itself, "
                    "and a run of 0 episodes fits nothing, so its τ bounds would stay those measured on the init's "
                    f"fear ({', '.join(f'{n}={own[n]}' for n in moved)}): use sage gate refit-bounds {path} "
                    "--set gate.…"
                )
        try:
            return self.learner.load_state_dict(payload["state"], strict=False)
        except RuntimeError as exc:
            raise ValueError(f"--init {path}: network sizes differ from this run's config: {exc}") from None

    def _make_expert(self, source: str | None) -> Expert:
        if source is None or source == "scripted":
            return ScriptedExpert()
        if is_planner(source):  # a planner that is not a learner (core.planners), built per env
            checked_entry(source, self.run.sim)  # refused here: built in an episode, it would only end that one
            return PlannerExpert(source, self.run.sim)
        expert = load_agent(source)
        if (expert.meta.obs_dim, expert.meta.act_dim) != (self.obs_dim, self.act_dim):
            raise ValueError(
                f"--expert {source}: its policy takes {expert.meta.obs_dim} observations / {expert.meta.act_dim} "
                f"actions, this simulator has {self.obs_dim} / {self.act_dim}"
            )
        return PolicyExpert(expert.policy)

    def close(self) -> None:
        """Close the envs (a SUMO env releases its simulation)."""
        for env in self.envs.values():
            env.close()

    # -- pieces --------------------------------------------------------------------------------------
    def meta(self) -> AgentMeta:
        learner = self.learner
        return AgentMeta(
            method=self.agent_cfg.method,
            sim=self.run.sim,
            scenarios=list(self.run.scenarios),
            obs_dim=self.obs_dim,
            act_dim=self.act_dim,
            action_low=[float(x) for x in self.low],
            action_high=[float(x) for x in self.high],
            episodes=self.episodes_done,
            env_steps=learner.env_steps,
            updates=learner.updates,
            seed=self.run.seed,
            has_world_model=learner.world_model_ready(),
            extra={
                "init": self.run.init or "",
                "demo_episodes": self.run.demo_episodes,
                "expert": self.run.expert or "",
                "demo_expert": self.run.demo_expert or self.run.expert or "",
                "steps_done": self.steps_done,
            },
        )

    def gate_and_expert(self) -> tuple[Gate, Expert | None]:
        cfg, learner = self.agent_cfg, self.learner
        if cfg.takeover and cfg.takeover_rule == "supervisor":
            # the supervisor steps in on its own judgement (human-guided RL); no gate asks it
            return NoGate(), CostSupervisor(self.expert, cfg.supervisor_cost, cfg.gate.hold)
        if cfg.takeover:
            return learner.make_gate(), self.expert
        if learner.world_model is not None:
            return learner.make_gate(), None  # fear and curiosity are recorded; nobody takes over
        return NoGate(), None

    def demonstrate(self) -> list[dict[str, Any]]:
        """Expert-driven episodes into the buffer as intervention samples, then ``learner.pretrain()``."""
        rows: list[dict[str, Any]] = []
        if self.run.demo_episodes == 0 and not self.run.datasets:
            return rows
        demonstrator = self.demo_expert
        if self.run.demo_noise > 0 and demonstrator is not None:
            demonstrator = NoisyExpert(demonstrator, self.run.demo_noise, self.low, self.high, self.run.seed)
        runners = [
            Runner(
                env,
                self.learner,
                AlwaysGate(),
                demonstrator,
                seed=self.run.seed + DEMO_SEED_OFFSET + j * SCENARIO_SEED_STRIDE,
            )
            for j, env in enumerate(self.envs.values())
        ]
        ends: list[bool] = []  # per stored row: the last of its episode

        def store(record: StepRecord) -> None:
            self.learner.store(record)
            ends.append(record.done)

        for runner in runners:
            runner.step_listeners.append(store)
        scenarios = list(self.envs)
        first_step = self.steps_done
        for i in range(self.run.demo_episodes):
            cap = self._episode_cap()
            if self.run.demo_steps is not None:
                left = max(0, self.run.demo_steps - (self.steps_done - first_step))
                cap = left if cap is None else min(cap, left)
            if cap == 0:
                break
            j = i % len(runners)
            summary = runners[j].run_episode(cap)
            self.steps_done += summary.steps
            if ends:
                ends[-1] = True  # an episode cut by max_episode_steps ends here too
            rows.append(_tag(summary.as_row(), scenario=scenarios[j], phase="demo"))
        for source in self.run.datasets:
            loaded = expert_steps = 0
            for record in records(source, self.obs_dim, self.act_dim if not self.learner.encodes_actions else None):
                store(record)
                loaded += 1
                expert_steps += int(record.takeover)
            rows.append({"phase": "dataset", "dataset": source, "steps": loaded, "expert_steps": expert_steps})
        buffer = self.learner.buffer
        returns = None
        if len(ends) <= buffer.capacity:
            returns = returns_to_go(
                buffer.reward[: len(ends)], buffer.terminated[: len(ends)], np.array(ends), self.agent_cfg.gamma
            )
        stats = self.learner.pretrain(returns)
        if rows:
            rows[-1].update(stats)
        return rows

    def write_config(self) -> None:
        if self.out is None:
            return
        self.out.mkdir(parents=True, exist_ok=True)
        config = {
            "run": dataclasses.asdict(self.run),
            "agent": to_dict(self.saved_cfg),
            "meta": dataclasses.asdict(self.meta()),
        }
        if self.saved_cfg is not self.agent_cfg:
            config["ran_with"] = to_dict(self.agent_cfg)
        (self.out / "config.json").write_text(json.dumps(config, indent=2, default=str) + "\n")

    def checkpoint(self, final: bool = False) -> Path | None:
        if self.out is None:
            return None
        dtype = self.run.checkpoint_dtype
        if final:
            return save_checkpoint(self.out / FINAL_CHECKPOINT, self.learner, self.meta(), dtype, self.saved_cfg)
        name = f"episode_{self.episodes_done:05d}.pt"
        return save_checkpoint(self.out / CHECKPOINT_DIR / name, self.learner, self.meta(), dtype, self.saved_cfg)

    def _episode_cap(self) -> int | None:
        """Steps the next episode may take: the simulator's limit, cut at what is left of ``train_steps``."""
        cap = self.run.max_episode_steps
        if self.run.train_steps is not None:
            left = max(0, self.run.train_steps - self.steps_done)
            cap = left if cap is None else min(cap, left)
        return cap

    def _more_episodes(self) -> bool:
        if self.run.episodes is not None and self.episodes_done >= self.run.episodes:
            return False
        return self._episode_cap() != 0

    # -- the run -----------------------------------------------------------------------------------------
    def train(self) -> TrainResult:
        from tqdm import tqdm

        started = time.time()
        self.write_config()
        metrics_file = None if self.out is None else (self.out / "metrics.jsonl").open("a")
        demo_rows = self.demonstrate()
        for hook in self.before_episode:  # a protocol that splits the interaction budget learns what is left of it
            start = getattr(hook, "start_interaction", None)
            if callable(start):
                start(self.steps_done, self.run.train_steps)
        if metrics_file is not None:
            for row in demo_rows:
                metrics_file.write(json.dumps(row, default=_json_default) + "\n")
        gate, expert = self.gate_and_expert()
        scenarios = list(self.envs)
        runners = []
        for j, s in enumerate(scenarios):
            runner = Runner(self.envs[s], self.learner, gate, expert, seed=self.run.seed + j * SCENARIO_SEED_STRIDE)
            runner.step_listeners.append(self.learner.observe)
            if isinstance(expert, CostSupervisor):
                runner.step_listeners.append(expert.observe)
            runners.append(runner)
        by_steps = self.run.train_steps is not None
        bar = tqdm(
            total=self.run.train_steps if by_steps else self.run.episodes,
            initial=self.steps_done if by_steps else 0,
            desc=f"{self.agent_cfg.method} {self.run.sim} {','.join(scenarios)}",
            unit="step" if by_steps else "ep",
            disable=not self.progress,
            leave=False,
        )
        try:
            while self._more_episodes():
                i = self.episodes_done
                j = i % len(runners)
                cap = self._episode_cap()
                if self.run.refit_gated_share > 0:
                    gated = gated_episode(i // len(runners), self.run.refit_gated_share)
                    runners[j].set_expert(self.expert if gated else None)
                for hook in self.before_episode:
                    hook(i, runners[j])
                    hook_cap = getattr(hook, "episode_cap", None)
                    limit = hook_cap() if callable(hook_cap) else None
                    if limit is not None:
                        cap = limit if cap is None else min(cap, limit)
                summary = runners[j].run_episode(cap)
                self.episodes_done += 1
                self.steps_done += summary.steps
                row = self._row(summary, scenarios[j], started)
                if self.run.refit_gated_share > 0:
                    row["expert_behind_gate"] = runners[j].expert is not None
                self.rows.append(row)
                if metrics_file is not None:
                    metrics_file.write(json.dumps(row, default=_json_default) + "\n")
                    metrics_file.flush()
                bar.update(summary.steps if by_steps else 1)
                bar.set_postfix_str(progress_text(self.rows))
                every = self.run.checkpoint_every
                if every and self.episodes_done % every == 0 and self._more_episodes():
                    self.checkpoint()
        finally:
            bar.close()
            if metrics_file is not None:
                metrics_file.close()
        if self.run.world_model_only and len(self.learner.buffer) >= 10:
            self.learner.fit_world_model()  # on everything collected: the refit's only product
        if self.episodes_done > 0 and self.run.checkpoint_every:
            self.checkpoint()
        self.checkpoint(final=True)
        if self.out is not None and self.learner.last_calibration is not None:
            self.learner.last_calibration.save(self.out / CALIBRATION_FILE)
        self.write_config()
        return TrainResult(self.rows, self.learner, self.out, demo_rows, time.time() - started)

    def _row(self, summary: EpisodeSummary, scenario: str, started: float) -> dict[str, Any]:
        learner = self.learner
        stats = {k: float(v) for k, v in learner.info.items() if isinstance(v, int | float)}
        return _tag(
            summary.as_row(),
            episode=self.episodes_done - 1,
            scenario=scenario,
            phase="train",
            env_steps=learner.env_steps,
            steps_done=self.steps_done,
            updates=learner.updates,
            wall_time=round(time.time() - started, 2),
            **stats,
        )


def gated_episode(k: int, share: float) -> bool:
    """Whether a scenario's ``k``-th episode of a refit runs with the expert behind the gate: ``share`` of them,
    spread evenly (0.5: every second one)."""
    return math.floor((k + 1) * share) > math.floor(k * share)


def returns_to_go(reward: np.ndarray, terminated: np.ndarray, episode_end: np.ndarray, gamma: float) -> np.ndarray:
    """Discounted return from each row to the end of its episode (0 after a termination or an episode cut)."""
    out = np.zeros(len(reward), np.float32)
    running = 0.0
    for t in range(len(reward) - 1, -1, -1):
        if episode_end[t] or terminated[t] > 0.5:
            running = 0.0
        running = float(reward[t]) + gamma * running
        out[t] = running
    return out


def progress_text(rows: Sequence[dict[str, Any]], window: int = 10) -> str:
    """Return, success, takeover rate and fear over the last ``window`` episodes."""
    recent = rows[-window:]

    def mean(key: str) -> float:
        values = [float(r[key]) for r in recent if r.get(key) is not None and math.isfinite(float(r[key]))]
        return float(np.mean(values)) if values else math.nan

    parts = [f"ret {mean('return'):.1f}"]
    if any("success" in r for r in recent):
        parts.append(f"succ {mean('success'):.0%}")
    parts.append(f"takeover {mean('takeover_rate'):.0%}")
    fear = mean("mean_fear")
    if math.isfinite(fear):
        parts.append(f"fear {fear:.2f}")
    return " ".join(parts)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return str(value)


def train(
    run: RunConfig, agent: AgentConfig, make_env: EnvFactory, out: Path | None = None, progress: bool = True
) -> TrainResult:
    """Build a :class:`Trainer` and run it."""
    return Trainer(run, agent, make_env, out, progress).train()


# -- evaluation ----------------------------------------------------------------------------------------
def evaluate(
    policy: Policy | PlannerFactory,
    make_env: EnvFactory,
    scenarios: Sequence[str],
    episodes: int,
    seed: int = 0,
    gate_factory: Callable[[], Gate] | None = None,
    expert: bool = False,
    progress: bool = True,
    max_episode_steps: int | None = None,
) -> dict[str, list[dict[str, Any]]]:
    """Run ``policy`` deterministically for ``episodes`` per scenario; rows per scenario. ``policy`` may also be a
    factory ``env -> Policy`` (a planner, :mod:`core.planners`), built for each scenario's env.

    By default no gate and no expert (the learned policy alone, as the paper evaluates). ``gate_factory``
    adds a gate (fear and curiosity are then recorded) and ``expert=True`` lets it hand over to the
    scripted expert. Evaluation seeds are disjoint from training seeds.
    """
    from tqdm import tqdm

    results: dict[str, list[dict[str, Any]]] = {}
    total = episodes * len(scenarios)
    bar = tqdm(total=total, desc="eval", unit="ep", disable=not progress, leave=False)
    try:
        for j, s in enumerate(scenarios):
            env = make_env(s)
            try:
                gate = gate_factory() if gate_factory is not None else None
                runner = Runner(
                    env,
                    policy if hasattr(policy, "act") else policy(env),
                    gate,
                    ScriptedExpert() if expert else None,
                    seed=seed + EVAL_SEED_OFFSET + j * SCENARIO_SEED_STRIDE,
                    deterministic=True,
                )
                rows = []
                for _ in range(episodes):
                    rows.append(_tag(runner.run_episode(max_episode_steps).as_row(), scenario=s))
                    bar.update(1)
                    bar.set_postfix_str(f"scenario {s} " + progress_text(rows, window=len(rows)))
                results[s] = rows
            finally:
                env.close()
    finally:
        bar.close()
    return results


def evaluate_run(
    run: str | Path,
    make_env: EnvFactory,
    scenarios: Sequence[str],
    episodes: int,
    seed: int = 0,
    with_gate: bool = False,
    expert: bool = False,
    progress: bool = True,
) -> dict[str, list[dict[str, Any]]]:
    """Load a run (or checkpoint) and :func:`evaluate` its policy."""
    agent = load_agent(run)
    gate_factory = agent.make_gate if with_gate else None
    return evaluate(agent.policy, make_env, scenarios, episodes, seed, gate_factory, expert, progress)

"""Checkpoints, and loading a run (or one checkpoint of it) as a policy plus a SAGE gate.

A run folder (written by ``sage train``, :mod:`core.train`) holds ``config.json``, ``metrics.jsonl``,
``checkpoint.pt`` (the final one) and ``checkpoints/episode_NNNNN.pt`` (versions along the way). A checkpoint
is a ``torch.save`` of plain data: ``{"format", "version", "meta", "agent_config", "state"}`` where ``state``
holds the learner's module state dicts and tensors only, so it loads with ``torch.load(weights_only=True)``.

    agent = load_agent("policies/ugv-default")          # a run folder, or a .pt file
    agent.policy.act(obs, deterministic=True)             # core.loop.Policy
    gate = agent.make_gate(tau_max=0.7, hold_steps=8)     # core.loop.Gate (SageGate), GateConfig overrides
    agent.meta.method, agent.meta.sim, agent.meta.scenarios, agent.meta.obs_dim, agent.meta.act_dim

Runs without a world model (``sac``, ``td3`` by default) have no SAGE gate: ``make_gate`` raises
:class:`NoWorldModelError` (a ``LookupError``) naming the run; check ``agent.has_world_model`` first and
fall back to :class:`core.loop.NoGate`, or pass ``world_model_from=<another run>`` to gate this run's policy
with another run's world model.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from core.device import to_cpu
from core.familiar import STATE_KEY as BASE_FIRST_KEY
from core.familiar import BaseFirstPolicy
from core.protocol import Policy
from core.sage.config import AgentConfig, GateConfig, from_dict, set_field, to_dict, validate
from core.sage.gate import SageGate
from core.sage.learner import ActorLearner, BaseLearner
from core.sage.networks import Actor
from core.sage.world_model import EnsembleWorldModel

CHECKPOINT_FORMAT = "sage-checkpoint"
CHECKPOINT_VERSION = 1
FINAL_CHECKPOINT = "checkpoint.pt"
CHECKPOINT_DIR = "checkpoints"


class NoWorldModelError(LookupError):
    """The run trained no world model, so there is no SAGE gate for it."""


@dataclass
class AgentMeta:
    """What a checkpoint says about itself."""

    method: str
    sim: str
    scenarios: list[str]
    obs_dim: int
    act_dim: int
    action_low: list[float]
    action_high: list[float]
    episodes: int = 0
    """Training episodes behind this checkpoint (demonstrations excluded)."""
    env_steps: int = 0
    updates: int = 0
    seed: int = 0
    has_world_model: bool = False
    extra: dict[str, Any] = field(default_factory=dict)


FEAR_SHAPE = (
    "beta",
    "horizon",
    "aggregate",
    "discount",
    "tau_min_quantile",
    "tau_max_quantile",
    "imagined_contact",
    "contact_needs_closing",
    "contact_horizon",
    "contact_extrapolation",
    "mover_model",
    "mover_history",
    "mover_max_speed",
    "mover_max_size",
    "mover_min_speed",
)
"""Gate settings that change the fear a model's τ bounds were measured on (or the quantiles they were taken at):
a gate that sets one over a run's own needs the bounds measured again (``sage gate refit-bounds``)."""


def fear_shape_moved(own: GateConfig | dict[str, Any], new: GateConfig) -> list[str]:
    """The :data:`FEAR_SHAPE` settings in which ``new`` differs from ``own`` (a run's gate, or its saved dict),
    when ``new`` takes its bounds from data: those bounds were measured on ``own``'s fear."""
    if not new.tau_from_data:
        return []
    values = own if isinstance(own, dict) else dataclasses.asdict(own)
    moved = [name for name in FEAR_SHAPE if values.get(name, getattr(GateConfig, name)) != getattr(new, name)]
    if new.imagined_contact and values.get("contact_floors") != new.contact_floors:
        moved.append("contact_floors")  # another simulator's floors are another fear
    return moved


# -- writing --------------------------------------------------------------------------------------
def save_checkpoint(
    path: Path,
    learner: BaseLearner,
    meta: AgentMeta,
    dtype: str = "float32",
    config: AgentConfig | None = None,
    extra_state: dict[str, Any] | None = None,
) -> Path:
    """Write the learner's state (``dtype`` ``float16`` halves the file, for committed policies); ``config``: the
    learner config to record, when it is not the one the learner ran with (a world-model-only refit);
    ``extra_state``: entries beside the learner's (a fine-tuned version's base ground, :mod:`core.familiar`)."""
    if dtype not in ("float32", "float16"):
        raise ValueError(f"checkpoint dtype must be float32 or float16, got {dtype!r}")
    state = to_cpu(learner.state_dict())  # device-free: a run trained on a GPU loads on a CPU and back
    if extra_state:
        clash = sorted(set(extra_state) & set(state))
        if clash:
            raise ValueError(f"extra checkpoint entries {', '.join(clash)} would replace the learner's own")
        state.update(to_cpu(extra_state))
    if dtype == "float16":
        state = halved(state)
    payload = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "meta": dataclasses.asdict(meta),
        "agent_config": _plain(to_dict(config or learner.cfg)),
        "state": state,
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)  # never leave a half-written checkpoint behind
    return path


def save_with_world_model(
    payload: dict[str, Any],
    out: Path,
    world_model: EnsembleWorldModel,
    agent_config: dict[str, Any],
    provenance: dict[str, Any],
    dtype: str = "float32",
) -> Path:
    """Write a run folder ``out`` (``checkpoint.pt``, ``config.json``) that is the loaded checkpoint ``payload``
    (:func:`load_checkpoint`) with another world model and learner config, every other tensor as it was: what
    ``sage gate merge`` and ``sage gate refit-bounds`` make from a run. ``provenance`` (JSON-ready) goes into the meta's
    ``extra`` and the top of ``config.json``, which starts from the source run's own when it has one."""
    if dtype not in ("float32", "float16"):
        raise ValueError(f"checkpoint dtype must be float32 or float16, got {dtype!r}")
    source = Path(payload["file"])
    out.mkdir(parents=True, exist_ok=True)
    written = dict(payload)
    written.pop("file", None)
    state = dict(written["state"])
    state["world_model"] = {name: value.detach().clone() for name, value in world_model.state_dict().items()}
    written["state"] = halved(state) if dtype == "float16" else state  # as save_checkpoint writes it
    written["agent_config"] = agent_config
    meta = dict(written["meta"])
    meta["extra"] = {**meta.get("extra", {}), **provenance}
    written["meta"] = meta
    tmp = out / (FINAL_CHECKPOINT + ".tmp")
    torch.save(written, tmp)
    tmp.replace(out / FINAL_CHECKPOINT)
    config_path = source.parent / "config.json"
    config: dict[str, Any] = json.loads(config_path.read_text()) if config_path.is_file() else {}
    config.update(agent=agent_config, meta=meta, **provenance)
    (out / "config.json").write_text(json.dumps(config, indent=2, default=str) + "\n")
    return out / FINAL_CHECKPOINT


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def halved(state: Any) -> Any:
    """A checkpoint state with every float32 tensor in float16 (``load_checkpoint`` widens them again). Float64
    tensors are descriptions, not weights (a world model's ego step geometry, which a warm start compares exactly),
    and stay as they are."""
    return _map_tensors(state, lambda t: t.half() if t.dtype == torch.float32 else t)


def _map_tensors(value: Any, fn: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return fn(value)
    if isinstance(value, dict):
        return type(value)((k, _map_tensors(v, fn)) for k, v in value.items())
    return value


# -- reading --------------------------------------------------------------------------------------
def resolve_checkpoint(path: str | Path) -> Path:
    """A checkpoint file from a file path or a run folder (its final checkpoint, else its latest version)."""
    p = Path(path)
    if p.is_file():
        return p
    if p.is_dir():
        if (p / FINAL_CHECKPOINT).is_file():
            return p / FINAL_CHECKPOINT
        versions = list_checkpoints(p)
        if versions:
            return versions[-1]
        raise FileNotFoundError(f"{p} holds no {FINAL_CHECKPOINT} and no {CHECKPOINT_DIR}/*.pt: not a run folder?")
    raise FileNotFoundError(f"no run folder or checkpoint file at {p}")


def list_checkpoints(run: str | Path) -> list[Path]:
    """The versions of a run, oldest first (``checkpoints/episode_NNNNN.pt``)."""
    folder = Path(run) / CHECKPOINT_DIR
    return sorted(folder.glob("*.pt")) if folder.is_dir() else []


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint's payload (tensors as float32), after checking that it is one of ours."""
    file = resolve_checkpoint(path)
    try:
        payload = torch.load(file, map_location="cpu", weights_only=True)
    except Exception as exc:
        # torch's own message may advise weights_only=False, which would run arbitrary code from the file: never
        # pass that advice on
        raise ValueError(f"{file} is not a readable SAGE checkpoint ({type(exc).__name__})") from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{file} is not a SAGE checkpoint (no format {CHECKPOINT_FORMAT!r})")
    if payload.get("version") != CHECKPOINT_VERSION:
        raise ValueError(
            f"{file} has checkpoint version {payload.get('version')}, this code reads {CHECKPOINT_VERSION}"
        )
    payload["state"] = _map_tensors(payload["state"], lambda t: t.float() if t.is_floating_point() else t)
    payload["file"] = str(file)
    from core.learners import learner_names

    # the registry names its built-in learners on first use: before then the method of a saved config (a discrete
    # policy's sage-d3qn) would fail validation wherever the config is edited (a refit's or a fine-tune's --set)
    learner_names()
    return payload


def meta_of(payload: dict[str, Any]) -> AgentMeta:
    return AgentMeta(**payload["meta"])


@dataclass
class LoadedAgent:
    """A trained run as the loop needs it: a policy, and a gate on its world model."""

    path: Path
    """The checkpoint file that was loaded."""
    meta: AgentMeta
    config: AgentConfig
    learner: BaseLearner
    """The run's learner, built for acting only (its networks loaded, frozen)."""
    world_model: EnsembleWorldModel | None
    policy: Policy
    """``policy.act(obs, deterministic)`` (:class:`core.loop.Policy`): a :class:`LearnerPolicy`, or a
    :class:`core.familiar.BaseFirstPolicy` for a fine-tuned version that lets the base drive first; the training-time
    stochastic policy when ``deterministic`` is False."""
    gate_state: dict[str, float] = field(default_factory=dict)

    @property
    def has_world_model(self) -> bool:
        return self.world_model is not None and bool(self.world_model.fitted)

    @property
    def actor(self) -> Actor:
        """The continuous actor of an actor-based run (a value-based run has none: AttributeError)."""
        learner = self.learner
        if not isinstance(learner, ActorLearner):  # D3QN's Q-network, the diffusion policy's denoiser
            raise AttributeError(f"a {type(learner).__name__} run has no continuous actor")
        return learner.actor

    def gate_config(self, **overrides: Any) -> GateConfig:
        """The run's gate settings with ``overrides`` (GateConfig field names; unknown names are an error). An
        explicit ``hold_steps`` (without ``hold_seconds``) is the hold: it clears the run's ``hold_seconds``."""
        cfg = dataclasses.replace(self.config.gate)
        if "hold_steps" in overrides and "hold_seconds" not in overrides:
            overrides = {**overrides, "hold_seconds": None}
        for key, value in overrides.items():
            set_field(cfg, key, value)
        probe = dataclasses.replace(self.config, gate=cfg)
        validate(probe)
        return cfg

    def make_gate(self, world_model_from: str | Path | LoadedAgent | None = None, **overrides: Any) -> SageGate:
        """A fresh :class:`SageGate` on this run's world model and policy (its curiosity average restored), built by
        the learner's own :meth:`~core.sage.learner.BaseLearner.make_gate` once the settings are resolved.

        ``overrides``: any :class:`GateConfig` field (beta, horizon, aggregate, discount, tau_min, tau_max,
        curiosity_ema, use_curiosity, hold_steps, hold_seconds, release). ``world_model_from``: take the world model
        of another run (e.g. to gate a plain SAC policy). Raises :class:`NoWorldModelError` when there is none.
        """
        source: LoadedAgent = self
        if world_model_from is not None:
            source = world_model_from if isinstance(world_model_from, LoadedAgent) else load_agent(world_model_from)
            if source.meta.obs_dim != self.meta.obs_dim or source.meta.act_dim != self.meta.act_dim:
                raise ValueError(f"world model of {source.path} does not fit the dimensions of {self.path}")
        if source.world_model is None or not source.has_world_model:
            raise NoWorldModelError(
                f"run {source.path} (method {source.meta.method}) has no trained world model, so no SAGE gate; "
                "use core.loop.NoGate, or make_gate(world_model_from=<a run with one>)"
            )
        cfg = self.gate_config(**overrides)
        own = source.config.gate
        moved = fear_shape_moved(own, cfg)
        if moved:
            raise ValueError(
                f"gate setting {', '.join(f'{n}={getattr(cfg, n)}' for n in moved)} changes fear itself, and the "
                f"τ bounds of {source.path} were measured on its fear with "
                f"{', '.join(f'{n}={getattr(own, n)}' for n in moved)}: recalibrate them first "
                "(sage gate refit-bounds RUN --set gate.…), or give the bounds (tau_from_data=false, tau_min, tau_max)"
            )
        state = self.gate_state if source is self else None  # another run's curiosity average is not this one's
        return self.learner.make_gate(cfg, world_model=source.world_model, state=state)


def load_agent(path: str | Path) -> LoadedAgent:
    """Load a run folder or checkpoint file as policy + gate (see the module docstring)."""
    payload = load_checkpoint(path)
    meta = meta_of(payload)
    config = from_dict(payload["agent_config"])
    state = payload["state"]
    learner = _learner_for_acting(payload["file"], meta, config)
    parts = {name: value for name, value in state.items() if name not in ("world_model", "gate", BASE_FIRST_KEY)}
    try:
        loaded = learner.load_state_dict(parts, strict=False)
    except RuntimeError as exc:
        raise ValueError(f"{payload['file']}: actor weights do not match its config: {exc}") from None
    acting = learner.acting_module
    if acting not in loaded:
        raise ValueError(f"{payload['file']}: the checkpoint holds no {acting} (it has {', '.join(sorted(state))})")
    for name in learner.declared_state().modules:
        getattr(learner, name).requires_grad_(False).eval()
    world_model = None
    if "world_model" in state:
        world_model = learner.new_world_model()
        try:
            world_model.load_state_dict(state["world_model"])
        except RuntimeError as exc:
            raise ValueError(f"{payload['file']}: world model weights do not match its config: {exc}") from None
        world_model.requires_grad_(False).eval()
    gate_state = {k: float(v) for k, v in state.get("gate", {}).items() if math.isfinite(float(v))}
    policy: Policy = LearnerPolicy(learner)
    if BASE_FIRST_KEY in state:
        policy = _base_first_policy(
            payload["file"], meta, config, learner, world_model, state[BASE_FIRST_KEY], gate_state
        )
    return LoadedAgent(Path(payload["file"]), meta, config, learner, world_model, policy, gate_state)


def _base_first_policy(
    file: str,
    meta: AgentMeta,
    config: AgentConfig,
    learner: BaseLearner,
    world_model: EnsembleWorldModel | None,
    saved: dict[str, Any],
    gate_state: dict[str, float],
) -> BaseFirstPolicy:
    """A fine-tuned version that lets the base drive first (:mod:`core.familiar`): the base's acting weights in a
    second learner of the same configuration, watched by a gate on the version's world model and settings."""
    if world_model is None or not world_model.fitted:
        raise ValueError(f"{file}: it lets the base drive first, but has no fitted world model to watch the base with")
    base = _learner_for_acting(file, meta, config)
    try:
        base.load_state_dict({base.acting_module: saved["acting"]}, strict=False)
    except (KeyError, RuntimeError) as exc:
        raise ValueError(f"{file}: the base weights it carries do not fit its config: {exc}") from None
    getattr(base, base.acting_module).requires_grad_(False).eval()
    watch = base.make_gate(config.gate, world_model=world_model, state=gate_state)
    return BaseFirstPolicy(LearnerPolicy(learner), LearnerPolicy(base), watch)


class LearnerPolicy:
    """A :class:`core.loop.Policy` that acts as the loaded learner does (its own exploration, e.g. TD3's
    Gaussian noise, when ``deterministic`` is False; HG-DAgger never explores)."""

    def __init__(self, learner: BaseLearner) -> None:
        self.learner = learner

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return self.learner.policy_action(obs, deterministic)


def _learner_for_acting(file: str, meta: AgentMeta, config: AgentConfig) -> BaseLearner:
    """The run's learner class from the registry, built for acting only (a one-slot replay buffer, no world
    model or virtual buffer: the world model is loaded on its own below, whatever the method's switches)."""
    from core.learners import learner_names, make_learner

    if meta.method not in learner_names():
        raise ValueError(f"{file}: method {meta.method!r} is not a registered learner ({', '.join(learner_names())})")
    acting = dataclasses.replace(config, buffer_size=1, virtual_size=1, world_model=False, virtual_rollouts=False)
    low = np.asarray(meta.action_low, np.float32)
    high = np.asarray(meta.action_high, np.float32)
    with torch.random.fork_rng(devices=[]):  # a learner seeds torch when built: loading must not reseed the caller
        return make_learner(meta.method, acting, meta.obs_dim, meta.act_dim, low, high, meta.seed)


def read_run_config(run: str | Path) -> dict[str, Any]:
    """The ``config.json`` of a run folder."""
    file = Path(run) / "config.json"
    if not file.is_file():
        raise FileNotFoundError(f"{run} has no config.json")
    return json.loads(file.read_text())


def action_bounds(space: Any) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of the action space as float32 arrays: a Box's bounds, or for a ``Discrete(n)`` space the
    index range ``[start, start + n - 1]`` as one value (a discrete learner reads ``n`` from it)."""
    n, start = getattr(space, "n", None), getattr(space, "start", None)
    if n is not None and start is not None and np.ndim(n) == 0:  # Discrete (MultiBinary has n but no start)
        return np.array([int(start)], np.float32), np.array([int(start) + int(n) - 1], np.float32)
    low, high = getattr(space, "low", None), getattr(space, "high", None)
    if low is None or high is None:
        raise TypeError(f"action space {space} is neither a Box nor a Discrete space")
    return np.asarray(low, np.float32).reshape(-1), np.asarray(high, np.float32).reshape(-1)


def warm_gate_kernels(policies: list[str]) -> list[str]:
    """Build (or load from numba's cache) each policy's compiled gate kernel by one decision and one observation of
    its gate on zero states, so that a fresh install pays the one-off compile (seconds) here and not in the first
    step of a live loop; with the mover model, also its compiled velocities (a track of ``gate.mover_history`` steps)
    and the movers' contact test (a kernel call with a moving sector); and the compiled reused curiosity whatever the
    gate's curiosity signal. Returns the policies whose gate runs compiled
    (those with a world model and a continuous actor the compiled kernel covers)."""
    import torch

    from core.sage.compiled_gate import CompiledGateKernel

    compiled = []
    for path in policies:
        agent = load_agent(path)
        if not agent.has_world_model:
            continue
        gate = agent.make_gate()
        obs = np.zeros(agent.meta.obs_dim, dtype=np.float32)
        action = np.zeros(agent.meta.act_dim, dtype=np.float32)
        gate.decide(obs, action)
        gate.observe(obs, action, obs)
        kernel = gate.kernel()
        if gate.cfg.mover_model != "none" and gate.world_model.ego is not None:
            for _ in range(gate.cfg.mover_history):
                gate.observe(obs, action, obs)
            gate.decide(obs, action)  # the velocities of a full track
            if isinstance(kernel, CompiledGateKernel) and kernel.contact is not None:
                moving = torch.zeros(1, gate.world_model.ego.sectors, 2)
                moving[0, 0] = 1.0
                with torch.inference_mode():
                    o, a = torch.from_numpy(obs).view(1, -1), torch.from_numpy(action).view(1, -1)
                    kernel(o, a, None, None, moving)
            gate.reset()
        if isinstance(kernel, CompiledGateKernel):
            # numba's cache is shared by every policy: compile the reused curiosity too, whichever curiosity this
            # gate reads, or the next gate that reads it compiles it inside a live loop's first step
            with torch.inference_mode():
                o, a = torch.from_numpy(obs).view(1, -1), torch.from_numpy(action).view(1, -1)
                kernel(o, a)
                kernel.curiosity(o, a, o, reuse_first_step=True)
            compiled.append(path)
    return compiled

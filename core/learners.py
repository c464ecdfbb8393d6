"""The learner registry: one entry per training method (its learner class and its configuration preset).

Every learner is built here, by name (:func:`make_learner`; a run's config names its method, ``cfg.method``). A new
method (e.g. a discrete-action D3QN) registers itself once:

    register_learner("my-method", MyLearner, preset=my_preset)
    learner = make_learner("my-method", cfg, obs_dim, act_dim, low, high, seed=0)
    learner_names()                                    # every registered method, in registration order

``preset(base, **overrides) -> AgentConfig`` builds the method's configuration (the built-in methods use
:func:`core.sage.config.for_method`). Pure torch/numpy: nothing here imports a simulator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from core.sage.config import AgentConfig, note_method, set_field, validate
from core.sage.learner import BaseLearner

Preset = Callable[..., AgentConfig]
"""``preset(base: AgentConfig | None = None, **overrides) -> AgentConfig``."""


@dataclass(frozen=True)
class LearnerEntry:
    """One registered method."""

    name: str
    cls: type[BaseLearner]
    """Built as ``cls(cfg, obs_dim, act_dim, action_low, action_high, seed)``."""
    preset: Preset
    """The method's configuration preset."""


_REGISTRY: dict[str, LearnerEntry] = {}


def register_learner(name: str, cls: type[BaseLearner], preset: Preset, replace: bool = False) -> None:
    """Register method ``name``; registering a taken name is an error unless ``replace``."""
    if not name or not isinstance(name, str):
        raise ValueError(f"a learner name must be a non-empty string, got {name!r}")
    if not (isinstance(cls, type) and issubclass(cls, BaseLearner)):
        raise TypeError(f"learner {name!r}: {cls!r} is not a BaseLearner subclass")
    _builtins()
    if name in _REGISTRY and not replace:
        raise ValueError(f"learner {name!r} is already registered (pass replace=True to override it)")
    _REGISTRY[name] = LearnerEntry(name, cls, preset)
    note_method(name)


def unregister_learner(name: str) -> None:
    """Remove method ``name`` (tests register toy learners and remove them again)."""
    _builtins()
    if name not in _REGISTRY:
        raise KeyError(f"no learner {name!r}; registered: {', '.join(_REGISTRY)}")
    del _REGISTRY[name]
    note_method(name, known=False)


def learner_names() -> tuple[str, ...]:
    """Every registered method, built-ins first."""
    _builtins()
    return tuple(_REGISTRY)


def learner_entry(name: str) -> LearnerEntry:
    """The entry of ``name`` (a clear error naming the choices otherwise)."""
    _builtins()
    if name not in _REGISTRY:
        raise ValueError(f"unknown method {name!r}; choose one of {', '.join(_REGISTRY)}")
    return _REGISTRY[name]


def preset(name: str, base: AgentConfig | None = None, **overrides: Any) -> AgentConfig:
    """The configuration preset of method ``name`` (see :func:`core.sage.config.for_method`)."""
    return learner_entry(name).preset(base, **overrides)


def make_learner(
    name: str,
    cfg: AgentConfig,
    obs_dim: int,
    act_dim: int,
    action_low: np.ndarray | None = None,
    action_high: np.ndarray | None = None,
    seed: int = 0,
    *,
    device: str | torch.device = "cpu",
) -> BaseLearner:
    """A fresh learner of method ``name`` built from ``cfg``, its update on ``device`` (``auto``, ``cpu``, ``cuda``:
    :func:`core.device.resolve_device`)."""
    return learner_entry(name).cls(cfg, obs_dim, act_dim, action_low, action_high, seed, device=device)


_BUILTINS_DONE = False


def _builtins() -> None:
    """Register the built-in methods on first use (lazily: the learner modules import torch networks)."""
    global _BUILTINS_DONE
    if _BUILTINS_DONE:
        return
    _BUILTINS_DONE = True
    from core.sage.config import for_method
    from core.sage.d3qn import D3QN, DiscreteHGDAgger
    from core.sage.hg_dagger import HGDAgger
    from core.sage.sac import SAC
    from core.sage.td3 import TD3

    classes: dict[str, type[BaseLearner]] = {"sage": SAC, "sac": SAC, "fni-rl": SAC, "td3": TD3, "hg-dagger": HGDAgger}
    for method, cls in classes.items():
        _REGISTRY[method] = LearnerEntry(method, cls, _method_preset(method, for_method))
    # discrete actions: the same switches as SAGE-SAC and plain SAC, on a dueling double-Q network
    discrete: tuple[tuple[str, type[BaseLearner], str], ...] = (
        ("d3qn", D3QN, "sac"),
        ("sage-d3qn", D3QN, "sage"),
        ("hg-dagger-discrete", DiscreteHGDAgger, "hg-dagger"),
    )
    for method, cls, switches in discrete:
        _REGISTRY[method] = LearnerEntry(method, cls, _switched_preset(method, switches, for_method))
        note_method(method)
    # offline diffusion policies (the paper's UGV baselines): every SAGE extra off, as plain SAC
    from core.sage.diffusion import DiffusionPolicy

    for method, q_weight in (("diffusion-bc", 0.0), ("diffusion-ql", 1.0)):
        fixed = {"diffusion.q_weight": q_weight}
        _REGISTRY[method] = LearnerEntry(method, DiffusionPolicy, _switched_preset(method, "sac", for_method, fixed))
        note_method(method)
    # human-guided RL: SAC whose supervisor decides the takeovers (core.sage.multi_hug)
    from core.sage.multi_hug import PRESET, MultiHug

    _REGISTRY["multi-hug"] = LearnerEntry(
        "multi-hug", MultiHug, _switched_preset("multi-hug", "sac", for_method, PRESET)
    )
    note_method("multi-hug")


def _switched_preset(
    method: str, switches_of: str, for_method: Callable[..., AgentConfig], fixed: dict[str, Any] | None = None
) -> Preset:
    """A preset with the switches of built-in method ``switches_of`` and the method's own ``fixed`` settings (dotted
    names), named ``method``; overrides apply last."""

    def build(base: AgentConfig | None = None, **overrides: Any) -> AgentConfig:
        cfg = for_method(switches_of, base)
        cfg.method = method
        for key, value in {**(fixed or {}), **overrides}.items():
            set_field(cfg, key, value)
        validate(cfg)
        return cfg

    build.__doc__ = f"The switches of {switches_of!r}, for method {method!r}."
    return build


def _method_preset(method: str, for_method: Callable[..., AgentConfig]) -> Preset:
    def build(base: AgentConfig | None = None, **overrides: Any) -> AgentConfig:
        return for_method(method, base, **overrides)

    build.__doc__ = f"The {method!r} preset of core.sage.config.for_method."
    return build

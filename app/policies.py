"""Which policies the dashboard can run: trained agents found under ``runs/`` and ``policies/``, plus
the simulator's scripted expert as a policy (no gate) for when no trained agent fits.

A trained agent is loaded with ``core.agents.load_agent(path)``, which gives its policy and its SAGE
gate (fear / curiosity / threshold). Every run folder is offered, and each checkpoint version inside it
(``*.pt`` files, directly or under ``checkpoints/``) as its own choice.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from core.loop import Gate, NoGate, Policy

log = logging.getLogger(__name__)

SCRIPTED = "scripted"
"""The policy choice that runs the simulator's scripted expert as the agent (no gate, no fear)."""

_META_FILES = ("meta.json", "agent.json", "config.json")


@dataclass(frozen=True)
class PolicyChoice:
    id: str
    """What the page sends back: ``"scripted"`` or a path (a run folder or a checkpoint file)."""
    label: str
    sim: str | None
    """The simulator the agent was trained on, when its metadata says so."""

    def as_dict(self) -> dict[str, Any]:
        return {"id": self.id, "label": self.label, "sim": self.sim}


def _meta(folder: Path) -> dict[str, Any]:
    for name in _META_FILES:
        path = folder / name
        if path.is_file():
            try:
                data = json.loads(path.read_text())
            except (OSError, ValueError):
                continue
            if isinstance(data, dict):
                return data
    return {}


def _sim_of(meta: dict[str, Any]) -> str | None:
    """The simulator named by a run's ``config.json`` (``{"run": {"sim"}, "meta": {"sim"}}``) or similar."""
    for key in ("sim", "simulator"):
        if isinstance(meta.get(key), str):
            return meta[key]
    env_id = meta.get("env_id") or meta.get("env")
    if isinstance(env_id, str) and env_id.startswith("sage/"):
        return env_id.split("/", 1)[1].split("-", 1)[0].lower()
    for nested in ("meta", "run", "config"):
        if isinstance(meta.get(nested), dict):
            found = _sim_of(meta[nested])
            if found is not None:
                return found
    return None


def _looks_like_agent(folder: Path) -> bool:
    """A run folder with at least one checkpoint (a run still before its first one is not offered)."""
    return any(folder.glob("*.pt")) or any((folder / "checkpoints").glob("*.pt"))


def discover(roots: Iterable[Path], sim: str | None = None) -> list[PolicyChoice]:
    """Every agent folder and checkpoint under ``roots``, filtered to ``sim`` when their metadata names one;
    the registered planners (the scripted expert first of them) last."""
    choices: list[PolicyChoice] = []
    for root in roots:
        if not root.is_dir():
            continue
        for folder in sorted(p for p in root.iterdir() if p.is_dir()):
            if not _looks_like_agent(folder):
                continue
            agent_sim = _sim_of(_meta(folder))
            if sim is not None and agent_sim is not None and agent_sim != sim:
                continue
            name = f"{root.name}/{folder.name}"
            choices.append(PolicyChoice(str(folder), name, agent_sim))
            for version in sorted((folder / "checkpoints").glob("*.pt")):
                choices.append(PolicyChoice(str(version), f"{name} @ {version.stem}", agent_sim))
    import sims  # noqa: F401 (registers the simulators' planners)
    from core.planners import planners

    # planners that are not learners (the scripted expert, a local planner...), last
    choices += [PolicyChoice(entry.name, f"{entry.title}", None) for entry in planners(sim)]
    return choices


def default_policy(roots: Iterable[Path], sim: str) -> str:
    """The committed default policy for ``sim`` (``policies/<sim>-default``) when it exists, else the
    first agent found for ``sim``, else the scripted expert."""
    roots = list(roots)
    for root in roots:
        candidate = root / f"{sim}-default"
        if candidate.is_dir() and _looks_like_agent(candidate):
            return str(candidate)
    for choice in discover(roots, sim):
        if choice.sim == sim:
            return choice.id
    return SCRIPTED


@dataclass
class LoadedPolicy:
    policy: Policy
    gate: Gate
    label: str
    meta: dict[str, Any]


def load_policy(choice: str, env: gym.Env[Any, Any], gate_overrides: dict[str, Any] | None = None) -> LoadedPolicy:
    """Build the policy and its gate. Raises a clear error when the agent cannot be loaded."""
    import sims  # noqa: F401 (registers the simulators' planners)
    from core.planners import is_planner, make_planner, planner_entry

    if is_planner(choice):  # a planner (core.planners): it drives, there is no gate
        return LoadedPolicy(make_planner(choice, env), NoGate(), planner_entry(choice).title, {})
    path = Path(choice)
    if not path.exists():
        raise FileNotFoundError(f"no policy at {choice!r}")
    try:
        from core.agents import load_agent  # built by the SAGE learner; absent on an early checkout
    except ImportError as exc:
        raise RuntimeError(f"cannot load {choice!r}: core.agents is not available ({exc})") from exc
    agent = load_agent(path)
    meta = agent.meta
    obs_dim = int(np.prod(env.observation_space.shape or (0,)))
    act_dim = int(np.prod(env.action_space.shape or (1,)))
    if (meta.obs_dim, meta.act_dim) != (obs_dim, act_dim):
        raise ValueError(
            f"{choice} was trained on {meta.sim} with observation/action sizes {meta.obs_dim}/{meta.act_dim}, "
            f"this simulator has {obs_dim}/{act_dim}"
        )
    # a run without a world model (plain SAC / TD3) has no SAGE gate: it drives ungated
    gate: Gate = agent.make_gate(**(gate_overrides or {})) if agent.has_world_model else NoGate()
    if path.is_dir():
        label = f"{path.parent.name}/{path.name}"
    elif path.parent.name == "checkpoints":
        label = f"{path.parent.parent.name} @ {path.stem}"
    else:
        label = f"{path.parent.name} @ {path.stem}"
    return LoadedPolicy(agent.policy, gate, f"{label} ({meta.method})", dataclasses.asdict(meta))

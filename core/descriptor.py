"""What the rest of the product knows about a simulator, in one place: its :class:`SimDescriptor`.

Each simulator package exports ``DESCRIPTOR`` (see ``sims/<name>/descriptor.py``) and ``sims.SIMULATORS`` lists
the packages. Every other layer (the CLI's scenario names, the dashboard's picker, the operator's key mapping,
the live loop's clock, the study tables) reads the descriptor instead of keeping its own table, so adding a
simulator is one package plus one registry line.

Scenario names are strings (``"3"``, ``"c2"``, ``"test-adversarial"``); the same name means the same env on the
command line, in the dashboard and in a study. A simulator may also accept free-form names (a YAML file for
the UGV, a logged-scenario id for highway) through ``parse_scenario``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np


class ScenarioNameError(ValueError):
    """A scenario name the simulator does not know; the message lists the names it does."""


@dataclass(frozen=True)
class ScenarioSpec:
    """One named variant of a simulator."""

    name: str
    """The name used everywhere: CLI ``--scenario``, the dashboard's picker, study configs, run folders."""
    label: str
    """A short human description shown in the dashboard's picker."""
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    """Keyword arguments of ``gymnasium.make(env_id, ...)`` that build this variant."""


@dataclass(frozen=True)
class InputMapping:
    """From the operator's two manual axes (throttle and steer, each in [-1, 1]) to the simulator's action.

    ``throttle`` +1 is forward / accelerate; ``steer`` +1 is left (counter-clockwise). A ``Box`` action is
    scaled from [-1, 1] to its bounds; a ``Discrete`` one is mapped by ``discrete`` when given."""

    throttle_index: int | None
    """Action component driven by the throttle axis (None: not used)."""
    steer_index: int | None
    """Action component driven by the steer axis (None: not used)."""
    steer_sign: float = 1.0
    """+1 when a positive action component turns left (counter-clockwise)."""
    throttle_sign: float = 1.0
    """+1 when a positive action component speeds up."""
    discrete: Callable[[float, float], int] | None = None
    """For a ``Discrete`` action space: (throttle, steer) -> action index."""


@dataclass(frozen=True)
class SimDescriptor:
    """Everything the product needs to know about one simulator besides its env class."""

    name: str
    """Short name (``ugv``, ``highway``, ``sumo``): CLI ``--sim``, run folders, checkpoints."""
    title: str
    """Human name for the dashboard's picker."""
    env_id: str
    """gymnasium id (``sage/UGV-v0``), registered by the package on import."""
    entry_point: str
    """``module:Class`` of the env, for ``gymnasium.register``."""
    dt: float
    """Control period in seconds of simulated time per ``step`` (the live clock, calibration horizons)."""
    scenarios: tuple[ScenarioSpec, ...]
    """Named variants, in the order the dashboard lists them."""
    default_scenario: str
    """The scenario a command uses when none is given."""
    input_mapping: InputMapping
    """How the operator's keys and gamepad drive this simulator."""
    metric_columns: tuple[str, ...]
    """The episode metrics (``metrics()`` keys) that the paper's tables show, in order."""
    safe_action: tuple[float, ...] | int
    """The action that stops or brakes (never cruise): what the loop applies when nobody can drive."""
    contact_floors: tuple[float | None, ...] = ()
    """Where the observation itself shows a violation: channel i at or under ``contact_floors[i]`` (channels [0, n))
    means the ego touches something (the UGV: a lidar sector's range at or inside the robot's footprint; highway: a
    beam along the ego's lane at its bumper); None: channel i shows none by itself. A training run writes them into
    its gate (``GateConfig.contact_floors``), for fear's imagined contact. Empty: the observation alone does not show
    one."""
    live_options: Mapping[str, Any] = field(default_factory=dict)
    """Extra ``make`` keyword arguments for the live server (e.g. SUMO in its own process)."""
    parse_scenario: Callable[[str], dict[str, Any]] | None = None
    """Keyword arguments for a name outside ``scenarios`` (a YAML path, a pool id); raises ``ValueError``."""

    def __post_init__(self) -> None:
        if not self.dt > 0:
            raise ValueError(f"{self.name}: dt must be positive, got {self.dt}")
        names = [s.name for s in self.scenarios]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.name}: duplicate scenario names in {names}")
        if self.default_scenario not in names:
            raise ValueError(f"{self.name}: default scenario {self.default_scenario!r} is not one of {names}")

    def scenario(self, name: str) -> ScenarioSpec | None:
        key = name.strip().lower()
        for spec in self.scenarios:
            if spec.name.lower() == key:
                return spec
        return None

    def scenario_kwargs(self, name: str | None) -> dict[str, Any]:
        """``gymnasium.make`` keyword arguments of a scenario name (``None``: the default scenario)."""
        key = self.default_scenario if name is None else str(name).strip()
        spec = self.scenario(key)
        if spec is not None:
            return dict(spec.kwargs)
        if self.parse_scenario is not None:
            try:
                return dict(self.parse_scenario(key))
            except ValueError as exc:
                raise ScenarioNameError(f"{self.name} scenario {key!r}: {exc}") from None
        known = ", ".join(s.name for s in self.scenarios)
        raise ScenarioNameError(f"{self.name} has no scenario {key!r}; choose one of {known}")

    def make(self, scenario: str | None = None, *, live: bool = False, **overrides: Any) -> gym.Env[Any, Any]:
        """Build the env of a scenario (``live`` adds ``live_options``); overrides win over both."""
        if self.env_id not in gym.registry:
            gym.register(id=self.env_id, entry_point=self.entry_point)
        kwargs = {**self.scenario_kwargs(scenario), **(dict(self.live_options) if live else {}), **overrides}
        return gym.make(self.env_id, **kwargs)

    def safe(self, action_space: gym.Space[Any]) -> np.ndarray:
        """``safe_action`` as an array of ``action_space``."""
        if isinstance(action_space, gym.spaces.Discrete):
            return np.asarray(int(self.safe_action), dtype=np.int64)  # type: ignore[arg-type]
        return np.asarray(self.safe_action, dtype=action_space.dtype).reshape(action_space.shape)

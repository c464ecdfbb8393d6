"""Every default of the highway simulator in one place (physics, sensing, reward, expert, adversary).

Units are SI (metres, seconds, radians). World frame: x east along the main road, y north; lane 0 is
the leftmost lane (largest y), higher lane indices lie to the right (smaller y), as a driver sees them.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class EgoLimits:
    """How the normalised action [steer, acc] in [-1, 1]^2 maps to physical commands."""

    max_steer: float = 0.25
    """Front-wheel angle at steer = ±1 [rad] (highway-env's bicycle model; positive turns left)."""
    max_accel: float = 3.0
    """Throttle at acc = +1 [m/s²]."""
    max_brake: float = 7.0
    """Braking at acc = -1 [m/s²]; stronger than any opponent brakes, so a cut-in can be survived."""
    max_speed: float = 40.0
    length: float = 5.0
    width: float = 2.0


@dataclass(frozen=True)
class SensorConfig:
    beams: int = 72
    """LiDAR-style beams spread evenly over 360°, starting straight ahead (the paper: 72)."""
    range: float = 50.0
    """Beam range [m] (the paper: 50 m)."""
    checkpoint_spacing: float = 40.0
    """Route checkpoints lie on the ego's current lane every this many metres along the route."""
    speed_scale: float = 40.0
    """Speeds are divided by this in the observation."""
    ttc_cap: float = 10.0
    """Time-to-collision reported when nothing is closing in [s]."""
    gap_cap: float = 50.0
    """Gap to the nearest vehicle reported when none is within this distance [m]."""


@dataclass(frozen=True)
class RewardConfig:
    """The paper's driving reward r = (d_t - d_{t-1}) + r_crash + r_out and binary cost."""

    progress_weight: float = 1.0
    """Per metre of progress along the route."""
    crash_reward: float = -1.0
    offroad_reward: float = -10.0
    conflict_ttc: float = 3.0
    """A step is a traffic conflict (``info["conflict"]``, a near miss; no cost, no reward) when the time to contact
    with the vehicle ahead is under this [s]: the usual surrogate safety threshold of traffic conflict studies
    (1.5-3 s; the upper end, since the expert needs about a second to resolve one)."""
    conflict_gap: float = 1.5
    """... or when any vehicle's body is within this of the ego's [m] (a cut-in alongside has no time to contact)."""


@dataclass(frozen=True)
class TrafficConfig:
    reactive_followers: bool = True
    """Replayed vehicles that have the ego right ahead in their path slow down (IDM along their own
    logged path) instead of driving through it. Pure non-reactive replay (False) gets every ego that
    brakes for a cut-in rear-ended, which no driver could avoid; the paths stay the logged ones."""
    follower_max_brake: float = 6.0
    """Strongest braking a yielding follower applies [m/s²]."""
    follower_time_gap: float = 1.0
    follower_min_gap: float = 2.0


@dataclass(frozen=True)
class AdversaryConfig:
    """CAT-style risk-conditioned resampling of opponent behaviour (see sims/highway/adversary.py)."""

    opponents: int = 1
    """How many opponents are resampled per episode (one event each, at least ``event_spacing`` apart)."""
    event_spacing: float = 6.0
    """Minimum time between two resampled events [s]."""
    risk_weight: float = 8.0
    """beta in p(candidate) ∝ prior · exp(beta · risk): how hard the distribution is tilted towards risk."""
    first_event: float = 2.0
    """Earliest time an opponent starts a resampled manoeuvre [s]."""
    reaction_time: float = 0.4
    """Reaction time assumed when checking that braking alone can still avoid a candidate [s]."""
    avoid_brake: float = 6.0
    """Braking assumed for that check [m/s²] (the ego can brake harder: ``EgoLimits.max_brake``)."""
    min_clearance: float = 1.0
    """A candidate is kept only if that braking response keeps at least this gap [m]."""


@dataclass(frozen=True)
class ExpertConfig:
    horizon: float = 3.0
    """Safety-check horizon [s] over which candidate manoeuvres are forecast."""
    forecast_dt: float = 0.2
    time_gap: float = 1.2
    """IDM desired time gap [s]."""
    min_gap: float = 3.0
    """IDM jam distance, bumper to bumper [m]."""
    comfort_accel: float = 2.0
    comfort_brake: float = 3.0
    delta: float = 4.0
    politeness: float = 0.2
    lane_change_gain: float = 0.3
    """MOBIL: minimum acceleration advantage for a discretionary lane change [m/s²]."""
    lane_change_safe_brake: float = 3.0
    """MOBIL: strongest braking a lane change may impose on the new follower [m/s²]."""
    lane_change_interval: float = 1.0
    """MOBIL decisions at most this often [s]."""
    margin_long: float = 2.0
    """Extra clearance along the road in the safety check [m]."""
    alongside_time: float = 1.0
    """Defensive driving: the longest the expert rides alongside a vehicle in a neighbouring lane (within
    ``margin_long`` of overlapping it along the road) before it drops back [s]; a vehicle beside can cut in with
    less warning than braking needs. 0 turns the rule off."""
    alongside_speed_gap: float = 2.0
    """How much slower than the vehicle beside the expert then aims to drive, so that it falls back [m/s]."""
    margin_lat: float = 0.4
    """Extra clearance across the road in the safety check [m]."""
    lateral_time: float = 0.6
    """Lateral position time constant of the lane-centring controller [s]."""
    evasive_lateral_time: float = 0.4
    heading_time: float = 0.2
    max_heading: float = 0.15
    """Largest heading off the lane direction the lateral controller commands [rad]."""
    evasive_max_heading: float = 0.2


@dataclass(frozen=True)
class HighwayConfig:
    dt: float = 0.1
    """Control period [s] (10 Hz, as Waymo logs)."""
    ego: EgoLimits = field(default_factory=EgoLimits)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    traffic: TrafficConfig = field(default_factory=TrafficConfig)
    adversary: AdversaryConfig = field(default_factory=AdversaryConfig)
    expert: ExpertConfig = field(default_factory=ExpertConfig)
    scene_rays: bool = False
    """Include the LiDAR rays in ``scene()`` (costs a little per frame)."""


DEFAULT = HighwayConfig()

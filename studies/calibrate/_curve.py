"""The gate's operating curve: episodes with a violation against the takeover rate for fear at scaled τ, random
and curiosity-only gating and the expert alone, as independent points (CurvePlan, curve_point), and chosen points run
again on new seeds and pooled with the curve's (CurveExtension, pool_points, extension_rows)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict

import gymnasium as gym

from core.agents import load_agent
from core.loop import Gate
from core.metrics import difference_interval
from core.sage.gate import SageGate
from studies.calibrate._gated_runs import EVAL_SEED, run_gated
from studies.calibrate._gatings import CuriosityGate, RandomGate, firing_share, level_for_share
from studies.calibrate._metrics import violation_counts

CURVE_SCALES = (0.15, 0.3, 0.5, 0.7, 1.0, 1.4)
"""The scales on τ that the fear curve sweeps."""


EXPERT_ALONE = "expert alone"
"""The curve's floor: the scripted expert driving every step of the same episodes (takeover rate 1). Every gating
that hands it more of the steps tends towards it; where the points of two gatings both lie near it, neither can lie
clearly above the other."""

CurveCall = dict[str, Any]
"""One point's work: ``kind`` (``fear``, ``pilot``, ``random``, ``curiosity only`` or :data:`EXPERT_ALONE`) and its
``knob`` (τ's scale over the gate's own ``tau_scale``), ``rate`` (the takeover rate to match) and ``pilot``
(curiosities met with no gating)."""


@dataclass(frozen=True)
class CurvePlan:
    """The operating curve as independent pieces of work, so that a caller can run each on its own core (Ray tasks:
    ``experiments/calibration.py``): first the fear points, the curiosity pilot and the expert alone (:meth:`first`),
    then random and curiosity-only gating at the takeover rates the fear points reached (:meth:`second`). Run each
    call with :func:`curve_point`; :meth:`curve` puts the results together. :func:`operating_curve` runs them in
    turn."""

    scales: Sequence[float] = CURVE_SCALES

    def first(self) -> list[CurveCall]:
        return [{"kind": "fear", "knob": s} for s in self.scales] + [{"kind": "pilot"}, {"kind": EXPERT_ALONE}]

    def second(self, first: Sequence[Any]) -> list[CurveCall]:
        fear, pilot, _ = self._split(first)
        rates = sorted(p["takeover_rate"] for p in fear)
        return [
            {"kind": kind, "rate": rate} | ({"pilot": pilot} if kind == "curiosity only" else {})
            for rate in rates
            for kind in ("random", "curiosity only")
        ]

    def curve(self, first: Sequence[Any], second: Sequence[Any]) -> dict[str, list[dict[str, float]]]:
        fear, _, alone = self._split(first)
        calls = self.second(first)
        curve: dict[str, list[dict[str, float]]] = {"fear (SAGE)": list(fear), "random": [], "curiosity only": []}
        for call, point in zip(calls, second, strict=True):
            curve[call["kind"]].append(point)
        for points in curve.values():
            points.sort(key=lambda q: q["takeover_rate"])
        curve[EXPERT_ALONE] = [alone]
        return curve

    def _split(self, first: Sequence[Any]) -> tuple[list[dict[str, float]], list[float], dict[str, float]]:
        if len(first) != len(self.scales) + 2:
            raise ValueError(f"{len(first)} results for the {len(self.scales) + 2} calls of the curve's first stage")
        return list(first[: len(self.scales)]), list(first[-2]), first[-1]


def curve_point(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    episodes: int,
    call: CurveCall,
    max_steps: int | None = None,
    gate_settings: Mapping[str, Any] | None = None,
    first_seed: int = EVAL_SEED,
) -> Any:
    """One call of a :class:`CurvePlan` on the curve's episodes (the evaluation seeds, from ``first_seed``): a point
    (``fear``, ``random``, ``curiosity only``, :data:`EXPERT_ALONE`) as :func:`gate_with_expert` returns it with its
    ``knob``, or (``pilot``) the curiosities met with no gating. A ``random`` or ``curiosity only`` call with a
    ``knob`` (a firing share, a curiosity level) instead of a ``rate`` runs that gating at it as it is, without
    matching a rate: a measured point again on other seeds (:class:`CurveExtension`)."""
    agent = load_agent(run)
    settings = dict(gate_settings or {})
    own = agent.gate_config(**settings)
    hold = own.hold
    kind = call["kind"]
    # the random gate's own draws move with the episodes' seeds (0 on the curve's own, as before)
    draws = first_seed - EVAL_SEED

    def make_gate() -> SageGate:
        return agent.make_gate(**settings)

    def gated(gate: Gate) -> dict[str, float]:
        return run_gated(agent, make_env, gate, episodes, max_steps, first_seed=first_seed)

    if kind == "fear":
        # the knob scales τ over the gate's own: the SAGE gate itself at that gate.tau_scale, hold and hysteresis
        # as it runs
        knob = float(call["knob"])
        return {"knob": knob, **gated(agent.make_gate(**{**settings, "tau_scale": own.tau_scale * knob}))}
    if kind == "pilot":
        pilot = CuriosityGate(make_gate(), hold, math.inf)
        gated(pilot)
        return pilot.seen
    if kind == EXPERT_ALONE:
        return {"knob": 1.0, **gated(RandomGate(make_gate(), hold, 1.0, seed=draws))}
    if kind == "random":

        def gate_for_share(share: float) -> tuple[float, Gate]:
            return share, RandomGate(make_gate(), hold, share, seed=draws)

    elif kind == "curiosity only":

        def gate_for_share(share: float) -> tuple[float, Gate]:
            level = level_for_share(call["pilot"], share)
            return level, CuriosityGate(make_gate(), hold, level)

    else:
        raise ValueError(f"unknown curve call {kind!r}: fear, pilot, random, curiosity only or {EXPERT_ALONE}")
    if "knob" in call:
        knob = float(call["knob"])
        gate = (
            RandomGate(make_gate(), hold, knob, seed=draws)
            if kind == "random"
            else CuriosityGate(make_gate(), hold, knob)
        )
        return {"knob": knob, **gated(gate)}
    return _at_rate(float(call["rate"]), hold, gate_for_share, agent, make_env, episodes, max_steps, first_seed)


def operating_curve(
    run: str | Path,
    make_env: Callable[[], gym.Env[Any, Any]],
    episodes: int,
    scales: Sequence[float] = CURVE_SCALES,
    max_steps: int | None = None,
    gate_settings: Mapping[str, Any] | None = None,
    *,
    cpus: int | None = None,
    address: str | None = None,
) -> dict[str, list[dict[str, float]]]:
    """Episodes with a violation against the takeover rate for SAGE's gate (τ scaled), random gating and
    curiosity-only gating on the same seeds, and the scripted expert alone (:data:`EXPERT_ALONE`); random and
    curiosity-only gating are set to the takeover rates that the scaled gate reached (the firing probability from the
    rate; the curiosity level from a pilot's curiosity, corrected once), so that each fear point has a counterpart at
    about its own rate. The points one after another in this process, or with ``cpus`` or ``address`` each stage's
    points at once as Ray tasks (:func:`studies.sweep.run_tasks`: local Ray on ``cpus`` cores or the cluster at
    ``address``; ``make_env`` must then pickle), with the same seeds and so the same points."""
    plan = CurvePlan(scales)

    def points(calls: list[CurveCall]) -> list[Any]:
        if cpus is None and address is None:
            return [curve_point(run, make_env, episodes, call, max_steps, gate_settings) for call in calls]
        from studies.sweep import run_tasks

        common = {"run": str(run), "make_env": make_env, "episodes": episodes, "max_steps": max_steps}
        tasks = [common | {"call": call, "gate_settings": dict(gate_settings or {})} for call in calls]
        labels = [f"curve point {c['kind']}" + (f" at {c['rate']:.0%}" if "rate" in c else "") for c in calls]
        return run_tasks(curve_point, tasks, labels, address=address, cpus=cpus)

    first = points(plan.first())
    return plan.curve(first, points(plan.second(first)))


def _at_rate(
    rate: float,
    hold: int,
    gate_for_share: Callable[[float], tuple[float, Gate]],
    agent: Any,
    make_env: Callable[[], gym.Env[Any, Any]],
    episodes: int,
    max_steps: int | None,
    first_seed: int = EVAL_SEED,
) -> dict[str, float]:
    """A comparison gating's curve point at about takeover ``rate``: ``gate_for_share`` builds it (and names its
    knob) from a per-step firing share, first the share that independent firing would need, then once more scaled
    by how far the takeover rate missed (the expert's driving changes what the gating meets); the nearer point."""
    share = firing_share(rate, hold)
    tries = []
    for _ in range(2):
        knob, gate = gate_for_share(share)
        point = {"knob": knob, **run_gated(agent, make_env, gate, episodes, max_steps, first_seed=first_seed)}
        tries.append(point)
        reached = point["takeover_rate"]
        if abs(reached - rate) <= 0.02 or reached <= 0.0:
            break
        share = min(share * rate / reached, 1.0)
    return min(tries, key=lambda q: abs(q["takeover_rate"] - rate))


def pool_points(points: Sequence[Mapping[str, float]]) -> dict[str, float]:
    """One curve point from runs of the same gating at the same knob on disjoint seeds: counts added, rates weighted
    by the runs' steps (by their episodes where a run has no ``steps``: points measured before they were recorded),
    ``expert_steps_before_violation`` by the violations it is the mean of. ``fear_before_handoff``, a median, does
    not pool: nan."""
    if not points:
        raise ValueError("no points to pool")
    knobs = {float(p.get("knob", math.nan)) for p in points}
    if len(knobs) > 1 and not all(math.isnan(k) for k in knobs):
        raise ValueError(f"points at different knobs ({sorted(knobs)}) are not one point")
    episodes = [float(p["episodes"]) for p in points]
    counted = all("steps" in p for p in points)
    weights = [float(p["steps"]) for p in points] if counted else episodes
    total, weight = sum(episodes), sum(weights)
    pooled: dict[str, float] = {"knob": points[0].get("knob", math.nan), "episodes": total}
    if counted:
        pooled["steps"] = weight
    rates = sorted({key for p in points for key in p if key.startswith("takeover_")})
    for key in rates:
        pooled[key] = sum(float(p.get(key, 0.0)) * w for p, w in zip(points, weights, strict=True)) / max(weight, 1e-9)
    pooled["violation_rate"] = sum(violation_counts(dict(p))[0] for p in points) / max(total, 1.0)
    for key in (
        "violations_under_expert",
        "violations_handed_back",
        "violations_under_threshold",
        "violations_unforeseen",
    ):
        pooled[key] = sum(float(p.get(key, 0.0)) for p in points)
    under = [
        (float(p.get("violations_under_expert", 0.0)), float(p.get("expert_steps_before_violation", math.nan)))
        for p in points
    ]
    under = [(n, m) for n, m in under if n > 0 and math.isfinite(m)]
    pooled["expert_steps_before_violation"] = (
        sum(n * m for n, m in under) / sum(n for n, _ in under) if under else math.nan
    )
    pooled["fear_before_handoff"] = math.nan
    return pooled


@dataclass(frozen=True)
class ExtendedPoint:
    """A point of a :class:`CurveExtension`: which gating, at which knob, near which of fear's takeover rates, and
    the curve's own measurement of it (None for a point the curve lacked)."""

    kind: str
    knob: float
    near: float
    prior: dict[str, float] | None

    def call(self) -> CurveCall:
        """The :func:`curve_point` call that measures it again."""
        return {"kind": "fear" if self.kind == "fear (SAGE)" else self.kind, "knob": self.knob}


@dataclass(frozen=True)
class CurveExtension:
    """More episodes at chosen points of a measured operating curve, on seeds the curve did not use: where its points
    at some takeover rates were left undecided against a comparison gating. For each of ``rates``, fear's point
    nearest to it and, for each gating of ``against``, that gating's point nearest to fear's (within ``tolerance``,
    :func:`compare_curves`'s rule) run again at their own knobs, so that the new episodes pool with the curve's
    (:func:`pool_points`); where a gating has no point that near, one at the knob interpolated (linearly in takeover
    rate) between its two points around fear's rate, on the new episodes alone. Each point's new episodes start
    after the curve's (:meth:`first_seed`)."""

    rates: Sequence[float]
    against: Sequence[str] = ("random", "curiosity only")
    tolerance: float = 0.05

    def points(self, curve: Mapping[str, Sequence[dict[str, float]]]) -> list[ExtendedPoint]:
        fear = list(curve.get("fear (SAGE)", []))
        if not fear:
            raise ValueError("the curve has no fear points to extend")
        chosen: list[dict[str, float]] = []
        for rate in self.rates:
            near = min(fear, key=lambda q: abs(q["takeover_rate"] - rate))
            if abs(near["takeover_rate"] - rate) > self.tolerance:
                raise ValueError(
                    f"no fear point within {self.tolerance:.0%} of {rate:.0%} takeover (the curve's: "
                    + ", ".join(f"{q['takeover_rate']:.0%}" for q in fear)
                    + ")"
                )
            if near not in chosen:
                chosen.append(near)
        out: list[ExtendedPoint] = []
        for point in chosen:
            at = float(point["takeover_rate"])
            out.append(ExtendedPoint("fear (SAGE)", float(point["knob"]), at, point))
            for kind in self.against:
                others = sorted(curve.get(kind, []), key=lambda q: q["takeover_rate"])
                closest = min(others, key=lambda q: abs(q["takeover_rate"] - at), default=None)
                if closest is not None and abs(closest["takeover_rate"] - at) <= self.tolerance:
                    out.append(ExtendedPoint(kind, float(closest["knob"]), at, closest))
                    continue
                below = [q for q in others if q["takeover_rate"] <= at]
                above = [q for q in others if q["takeover_rate"] > at]
                if below and above:
                    lo, hi = below[-1], above[0]
                    t = (at - lo["takeover_rate"]) / (hi["takeover_rate"] - lo["takeover_rate"])
                    out.append(ExtendedPoint(kind, float(lo["knob"] + t * (hi["knob"] - lo["knob"])), at, None))
        return out

    @staticmethod
    def first_seed(curve: Mapping[str, Sequence[dict[str, float]]]) -> int:
        """The first evaluation seed the curve's points did not use."""
        return EVAL_SEED + max(int(q.get("episodes", 0)) for points in curve.values() for q in points)


class _Side(TypedDict):
    """One side of an :func:`extension_rows` row: the curve's point, the new episodes' and the two pooled."""

    prior: dict[str, float] | None
    new: dict[str, float]
    pooled: dict[str, float]
    knob: float


def extension_rows(points: Sequence[ExtendedPoint], new: Sequence[dict[str, float]]) -> list[dict[str, Any]]:
    """Fear's point against each other gating's near it, on the new episodes alone and pooled with the curve's:
    each row's counts and takeover rates and the 95% interval of the difference in the share of episodes with a
    violation (fear minus the other: :func:`core.metrics.difference_interval`), and the verdict read off the pooled
    one (better: wholly below 0). ``new[i]`` is ``points[i]``'s new episodes, pooled over their runs."""
    if len(points) != len(new):
        raise ValueError(f"{len(new)} results for {len(points)} points")
    rows: list[dict[str, Any]] = []
    fear: tuple[ExtendedPoint, dict[str, float]] | None = None
    for point, fresh in zip(points, new, strict=True):
        if point.kind == "fear (SAGE)":
            fear = (point, fresh)
            continue
        if fear is None or fear[0].near != point.near:
            raise ValueError(f"{point.kind} at {point.near:.0%} has no fear point before it")
        sides: list[_Side] = []
        for p, f in (fear, (point, fresh)):
            pooled = pool_points([p.prior, f]) if p.prior is not None else f
            sides.append({"prior": p.prior, "new": f, "pooled": pooled, "knob": p.knob})
        new_low, new_high = difference_interval(*violation_counts(sides[0]["new"]), *violation_counts(sides[1]["new"]))
        low, high = difference_interval(*violation_counts(sides[0]["pooled"]), *violation_counts(sides[1]["pooled"]))
        matched = abs(sides[0]["pooled"]["takeover_rate"] - sides[1]["pooled"]["takeover_rate"]) <= 0.05
        verdict = "unmatched" if not matched else "better" if high < 0 else "worse" if low > 0 else "tied"
        rows.append(
            {
                "near": point.near,
                "against": point.kind,
                "fear": sides[0],
                "other": sides[1],
                "new_interval": (new_low, new_high),
                "pooled_interval": (low, high),
                "verdict": verdict,
            }
        )
    return rows

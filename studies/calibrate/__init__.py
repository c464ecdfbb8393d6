"""Does fear predict danger? ``sage gate evaluate``: measure the self-awareness signals against what happened.

The policy drives with its SAGE gate and **no expert**, so danger plays out. Every step is labelled "a violation
happens within the next H seconds" (1 s by default; H / dt steps from the simulator's descriptor). Then:

- AUROC and average precision of fear F, of its parts ĉ (predicted violation probability) and σ̂ (normalised
  uncertainty), and of curiosity C (the one observed on arriving at the state) for that label;
- the gate's firing rate on pre-violation steps against the other steps;
- the share of violations preceded by a firing within H, and the lead time (first firing -> violation);
- a reliability diagram: predicted ĉ against the observed rate of violations within the model's horizon;
- the gate's operating curve (:func:`operating_curve`): with the gate and the scripted expert, episodes with a
  violation against the takeover rate, sweeping a scale on τ; beside random gating and curiosity-only gating
  swept over their own knobs, so that the three are compared at equal takeover rates.

:func:`expert_lead` asks the question the gate has to answer in time: how much warning does the expert need? It
replays each of the policy's violations with the expert taking over a given time before it, beside how long
before it the gate first fired.

One module per job; every public name is re-exported here:

- :mod:`._metrics`: labels, early warning, a curve point's interval, two gatings compared at equal takeover;
- :mod:`._calibration`: the measurement itself (:func:`calibrate_run`, :class:`CalibrationReport`);
- :mod:`._gatings`: the reference gatings (random, curiosity-only, InfoGate) with the SAGE gate's hold;
- :mod:`._gated_runs`: a gating driving with the scripted expert (:func:`run_gated`, :func:`gate_with_expert`);
- :mod:`._operating_point`: the gate table's target and the choice of ``gate.tau_scale``;
- :mod:`._curve`: the operating curve as independent points, and chosen points extended on new seeds;
- :mod:`._lead`: the warning the expert needs (:func:`expert_lead`);
- :mod:`._figures`: reliability diagram and operating curve.
"""

from __future__ import annotations

from core.loop import TAKEOVER_CAUSES as TAKEOVER_CAUSES

from ._calibration import CalibrationReport as CalibrationReport
from ._calibration import calibrate_run as calibrate_run
from ._calibration import collect as collect
from ._curve import CURVE_SCALES as CURVE_SCALES
from ._curve import EXPERT_ALONE as EXPERT_ALONE
from ._curve import CurveCall as CurveCall
from ._curve import CurveExtension as CurveExtension
from ._curve import CurvePlan as CurvePlan
from ._curve import ExtendedPoint as ExtendedPoint
from ._curve import curve_point as curve_point
from ._curve import extension_rows as extension_rows
from ._curve import operating_curve as operating_curve
from ._curve import pool_points as pool_points
from ._figures import write_figures as write_figures
from ._gated_runs import EVAL_SEED as EVAL_SEED
from ._gated_runs import gate_with_expert as gate_with_expert
from ._gated_runs import run_gated as run_gated
from ._gatings import CuriosityGate as CuriosityGate
from ._gatings import HoldGate as HoldGate
from ._gatings import InfoGate as InfoGate
from ._gatings import RandomGate as RandomGate
from ._gatings import firing_share as firing_share
from ._gatings import level_for_share as level_for_share
from ._lead import LeadReport as LeadReport
from ._lead import _episode as _episode
from ._lead import expert_lead as expert_lead
from ._metrics import EARLY_FIRING as EARLY_FIRING
from ._metrics import EARLY_LEAD_S as EARLY_LEAD_S
from ._metrics import SignalScore as SignalScore
from ._metrics import compare_curves as compare_curves
from ._metrics import early_warning as early_warning
from ._metrics import labels_within as labels_within
from ._metrics import violation_counts as violation_counts
from ._metrics import violation_interval as violation_interval
from ._operating_point import DEFAULT_SCALES as DEFAULT_SCALES
from ._operating_point import GateTarget as GateTarget
from ._operating_point import ScaleChoice as ScaleChoice
from ._operating_point import choose_tau_scale as choose_tau_scale
from ._operating_point import scaled_gate_row as scaled_gate_row

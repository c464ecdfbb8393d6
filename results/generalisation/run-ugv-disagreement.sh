#!/bin/sh
# Issue 60, the curiosity candidate (docs/notes/novelty_probe.md): curiosity as the ensemble's disagreement about the
# next state, read against its mean on the calibration states. τ bounds and the reference measured on DRIVES drives
# of each training scenario; then the test grounds under the amended rule, the 2+ ground first.
# Usage: run-ugv-disagreement.sh [DRIVES]
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=${PY:-.venv/bin/python}
DRIVES=${1:-50}
RUN=runs/ugv-disagreement
CACHE=results/generalisation/ugv-disagreement.json
SCRATCH=results/generalisation/scratch-disagreement.md
SEEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml
SETS="--set gate.curiosity_signal=disagreement --set gate.curiosity_reference=fitted"
TIME="/usr/bin/time -f %e_s_wall_%U_s_user_%M_kB_peak"
stamp() { echo "== $(date -u +%FT%TZ) $*"; }

stamp "refit-bounds (and the disagreement reference), $DRIVES drives a scenario"
[ -e $RUN/checkpoint.pt ] || $TIME $PY -m app.cli gate refit-bounds policies/ugv-default --scenario $SEEN $SETS \
    --episodes $DRIVES --out $RUN
stamp "test fields with two or more movers, 100 episodes (gate row 200)"
$TIME $PY -m studies.generalisation --sim ugv --run $RUN --episodes 100 --gate-episodes 200 --grounds unseen \
    --unseen ugv-fields:test:2+ --cache $CACHE --out $SCRATCH.crowded
$PY -m experiments.generalisation_rule --candidate $RUN --candidate-cache $CACHE --unseen ugv-fields:test:2+ \
    --episodes 200 --baseline-table docs/generalisation.md
stamp "unseen, 300 episodes (gate row 300)"
$TIME $PY -m studies.generalisation --sim ugv --run $RUN --episodes 300 --gate-episodes 300 --grounds unseen \
    --cache $CACHE --out $SCRATCH
stamp "seen, 300 episodes (gate row 300)"
$TIME $PY -m studies.generalisation --sim ugv --run $RUN --episodes 300 --gate-episodes 300 --grounds seen \
    --seen $SEEN --cache $CACHE --out $SCRATCH
stamp "the rule's reading"
$PY -m experiments.generalisation_rule --candidate $RUN --candidate-cache $CACHE --episodes 300 --seen-episodes 300 \
    --baseline-table docs/generalisation.md
stamp done

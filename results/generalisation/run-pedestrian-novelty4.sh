#!/bin/sh
# Issue 60, target 3 (docs/notes/curiosity_defaults.md, tenth session): the pedestrian default's gate with state-novelty
# curiosity whose reference set holds every built-in scenario (crossing, rare for the bounds and the set; clear, parked
# for the set only), then its seen/unseen table at 300 + 300 and its built-in gate rows (300 a scenario).
# KEEP=1: the second candidate, κ and the τ bounds kept as the default's (--keep-bounds; runs/pedestrian-novelty4k).
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=${PY:-.venv/bin/python}
RUN=runs/pedestrian-novelty4${KEEP:+k}
TIME="/usr/bin/time -f %e_s_wall_%U_s_user_%M_kB_peak"
stamp() { echo "== $(date -u +%FT%TZ) $* (at $(git rev-parse --short HEAD))"; }
cd "$(dirname "$0")/../.."
stamp "refit-bounds with the novelty's reference on every built-in scenario"
[ -e $RUN/checkpoint.pt ] || $TIME $PY -m app.cli gate refit-bounds policies/pedestrian-default --scenario crossing,rare \
    --novelty-scenario clear,parked --set gate.curiosity_signal=novelty --set gate.curiosity_reference=fitted \
    ${KEEP:+--keep-bounds} --episodes 50 --out $RUN
stamp "the candidate's table at 300 + 300"
$TIME $PY -m studies.generalisation --sim pedestrian --run $RUN --seen crossing,rare --episodes 300 --gate-episodes 300 \
    --cache results/generalisation/${RUN#runs/}.json --out results/generalisation/scratch-${RUN#runs/}.md
stamp "the candidate's built-in gate rows"
sh results/generalisation/run-curiosity-defaults.sh rows pedestrian $RUN results/generalisation/${RUN#runs/}-builtin-rows.json
stamp "done"

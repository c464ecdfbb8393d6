#!/bin/sh
# Issue 60: the extrapolating gate (gate.contact_extrapolation=true, gate.contact_horizon=10) at an operating point
# chosen on train ground only (docs/notes/generalisation.md, "an operating point for the extrapolating gate"). A copy
# of run-ugv-contact-extrapolation.sh with the paths changed and two stages added. Stages: bounds (refit-bounds on the
# four training scenarios' drives), choose (the baseline and the scale sweep on ugv-fields:train:2+, then the rule's
# choice), test (only for a chosen scale below 1: the test grounds under the amended rule, the 2+ ground first);
# "all" runs the three. Run from the worktree's root (its code is imported: python -m).
# Usage: [SCALE=X] run-ugv-extrapolation-oppoint.sh [DRIVES] [STAGE]  (SCALE: test at gate.tau_scale=X, not the rule's)
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=${PY:-/work/main/.venv/bin/python}
DRIVES=${1:-50}
STAGE=${2:-all}
EPISODES=150
RUN=runs/ugv-extrapolation-oppoint
CACHE=results/generalisation/ugv-extrapolation-oppoint.json
SCRATCH=results/generalisation/scratch-extrapolation-oppoint.md
BASELINE=results/generalisation/oppoint-baseline-train2.json
SWEEP=results/generalisation/oppoint-sweep-train2.json
SEEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml
TIME="/usr/bin/time -f %e_s_wall_%U_s_user_%M_kB_peak"
stamp() { echo "== $(date -u +%FT%TZ) $*"; }

if [ "$STAGE" = bounds ] || [ "$STAGE" = all ]; then
  stamp "refit-bounds for gate.contact_extrapolation=true, gate.contact_horizon=10, $DRIVES drives a scenario"
  [ -e $RUN/checkpoint.pt ] || $TIME $PY -m app.cli gate refit-bounds policies/ugv-default --scenario $SEEN \
      --set gate.contact_horizon=10 --set gate.contact_extrapolation=true --episodes $DRIVES --out $RUN
fi
if [ "$STAGE" = choose ] || [ "$STAGE" = all ]; then
  stamp "the baseline on ugv-fields:train:2+, $EPISODES episodes"
  [ -e $BASELINE ] || $TIME $PY -m app.cli gate choose-scale policies/ugv-default --scenario ugv-fields:train:2+ \
      --episodes $EPISODES --scale 1 --out $BASELINE
  TAKEOVER=$($PY -c "import json, sys; print(repr(json.load(open(sys.argv[1]))['rows'][0]['takeover_rate']))" $BASELINE)
  stamp "the sweep on ugv-fields:train:2+, $EPISODES episodes a scale, takeover target $TAKEOVER (the baseline's)"
  [ -e $SWEEP ] || $TIME $PY -m app.cli gate choose-scale $RUN --scenario ugv-fields:train:2+ --episodes $EPISODES \
      --scale 1 --scale 0.9 --scale 0.8 --scale 0.7 --violation-share 0 --takeover "$TAKEOVER" --out $SWEEP
  stamp "the rule's choice"
  $PY -m experiments.pick_operating_point --baseline $BASELINE --sweep $SWEEP
fi
if [ "$STAGE" = test ] || [ "$STAGE" = all ]; then
  CHOSEN=$($PY -m experiments.pick_operating_point --baseline $BASELINE --sweep $SWEEP --scale-only)
  if [ -n "$SCALE" ]; then
    # a scale set by hand over the rule's choice (the lead's follow-up in the note): its own cache and tables, so that
    # no row of another scale is mixed in
    CACHE=results/generalisation/ugv-extrapolation-oppoint-$SCALE.json
    SCRATCH=results/generalisation/scratch-extrapolation-oppoint-$SCALE.md
    stamp "gate.tau_scale=$SCALE set by hand (the rule's choice: $CHOSEN)"
  else
    SCALE=$CHOSEN
  fi
  if [ "$SCALE" = 1 ]; then
    stamp "chosen scale 1: the gate measured on test by run-ugv-contact-extrapolation.sh; nothing measured again"
  else
    stamp "test fields with two or more movers at gate.tau_scale=$SCALE, 100 episodes (gate row 200)"
    $TIME $PY -m studies.generalisation --sim ugv --run $RUN --set gate.tau_scale=$SCALE --episodes 100 \
        --gate-episodes 200 --grounds unseen --unseen ugv-fields:test:2+ --cache $CACHE --out $SCRATCH.crowded
    $PY -m experiments.generalisation_rule --candidate $RUN --candidate-set gate.tau_scale=$SCALE \
        --candidate-cache $CACHE --unseen ugv-fields:test:2+ --episodes 200 --baseline-table docs/generalisation.md
    stamp "unseen, 300 episodes (gate row 300)"
    $TIME $PY -m studies.generalisation --sim ugv --run $RUN --set gate.tau_scale=$SCALE --episodes 300 \
        --gate-episodes 300 --grounds unseen --cache $CACHE --out $SCRATCH
    stamp "seen, 300 episodes (gate row 300)"
    $TIME $PY -m studies.generalisation --sim ugv --run $RUN --set gate.tau_scale=$SCALE --episodes 300 \
        --gate-episodes 300 --grounds seen --seen $SEEN --cache $CACHE --out $SCRATCH
    stamp "the rule's reading"
    $PY -m experiments.generalisation_rule --candidate $RUN --candidate-set gate.tau_scale=$SCALE \
        --candidate-cache $CACHE --episodes 300 --seen-episodes 300 --baseline-table docs/generalisation.md
  fi
fi
stamp done

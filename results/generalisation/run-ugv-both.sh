#!/bin/sh
# Issue 60: the contact extrapolation and the disagreement curiosity together (docs/notes/novelty_probe.md, "The two
# together"). A copy of run-ugv-contact-extrapolation.sh with the settings and paths changed; stages train, then test.
# Usage: run-ugv-both.sh [DRIVES] [STAGE]
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=${PY:-.venv/bin/python}
DRIVES=${1:-50}
STAGE=${2:-train}
RUN=runs/ugv-both
CACHE=results/generalisation/ugv-both.json
SCRATCH=results/generalisation/scratch-both.md
SEEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml
TIME="/usr/bin/time -f %e_s_wall_%U_s_user_%M_kB_peak"
stamp() { echo "== $(date -u +%FT%TZ) $*"; }

if [ "$STAGE" = bounds ] || [ "$STAGE" = train ] || [ "$STAGE" = probe ]; then
  stamp "refit-bounds for gate.contact_extrapolation=true, gate.contact_horizon=10, $DRIVES drives a scenario"
  [ -e $RUN/checkpoint.pt ] || $TIME $PY -m app.cli gate refit-bounds policies/ugv-default --scenario $SEEN \
      --set gate.contact_horizon=10 --set gate.contact_extrapolation=true --set gate.curiosity_signal=disagreement --set gate.curiosity_reference=fitted --episodes $DRIVES --out $RUN
fi
if [ "$STAGE" = probe ]; then
  stamp "contact-reach probe: the eight late or missed collisions of the train diagnosis"
  $TIME $PY -m experiments.contact_reach_probe --run $RUN \
      --seeds 3000001,3000057,3000099,3000118,3000119,3000021,3000113,3000124 --window 15 \
      > results/generalisation/contact-reach-probe-extrapolation.md
elif [ "$STAGE" = train ]; then
  stamp "train check: ugv-fields:train:2+, 150 episodes"
  $TIME $PY -m experiments.collision_anatomy --run $RUN --episodes 150 \
      --out docs/notes/collision_anatomy_train2_both.md
elif [ "$STAGE" = test ]; then
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
fi
stamp done

#!/bin/sh
# Issue 60: the Cartesian mover model in the imagined contact test (gate.mover_model=cartesian,
# gate.contact_horizon=10; docs/notes/generalisation.md, "a Cartesian mover model"). A copy of
# run-ugv-extrapolation-oppoint.sh with the paths and the gate settings changed. Stages: bounds (refit-bounds on the
# four training scenarios' drives), choose (the sweep on ugv-fields:train:2+ at scales 1 and 0.9, then the rule's
# choice against the baseline's row read from the committed log of the operating-point run: it is not measured
# again), test (only for a chosen scale whose row has fewer collisions than the baseline's 13: the test grounds under
# the amended rule, the 2+ ground first); "all" runs the three. Run from the worktree's root (python -m imports it).
# Usage: run-ugv-mover-model.sh [DRIVES] [STAGE]
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=${PY:-/work/main/.venv/bin/python}
DRIVES=${1:-50}
STAGE=${2:-all}
EPISODES=150
RUN=runs/ugv-mover-model
CACHE=results/generalisation/ugv-mover-model.json
SCRATCH=results/generalisation/scratch-mover-model.md
BASELINE_LOG=results/generalisation/ugv-extrapolation-oppoint.log
BASELINE_VIOLATIONS=13
SWEEP=results/generalisation/mover-model-sweep-train2.json
SEEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml
GATE="--set gate.contact_horizon=10 --set gate.mover_model=cartesian"
TIME="/usr/bin/time -f %e_s_wall_%U_s_user_%M_kB_peak"
stamp() { echo "== $(date -u +%FT%TZ) $*"; }
# the baseline's unrounded takeover, as the operating-point run printed it (its JSON is gitignored)
TAKEOVER=$(sed -n 's/.*takeover target \([0-9.]*\) (the baseline.s).*/\1/p' $BASELINE_LOG)
PICK="import json, sys; from experiments.pick_operating_point import pick_scale
rows = json.load(open(sys.argv[1]))['rows']; s = pick_scale(rows, float(sys.argv[2]))
row = [r for r in rows if s is not None and float(r['scale']) == s]
print('none' if not row else ('%g' % s if int(row[0]['violations']) < int(sys.argv[3]) else 'none'))"

if [ "$STAGE" = bounds ] || [ "$STAGE" = all ]; then
  stamp "refit-bounds for gate.mover_model=cartesian, gate.contact_horizon=10, $DRIVES drives a scenario"
  [ -e $RUN/checkpoint.pt ] || $TIME $PY -m app.cli gate refit-bounds policies/ugv-default --scenario $SEEN \
      $GATE --episodes $DRIVES --out $RUN
fi
if [ "$STAGE" = choose ] || [ "$STAGE" = all ]; then
  stamp "the sweep on ugv-fields:train:2+, $EPISODES episodes a scale, takeover target $TAKEOVER (the baseline's, from $BASELINE_LOG)"
  [ -e $SWEEP ] || $TIME $PY -m app.cli gate choose-scale $RUN --scenario ugv-fields:train:2+ --episodes $EPISODES \
      --scale 1 --scale 0.9 --violation-share 0 --takeover "$TAKEOVER" --out $SWEEP
  stamp "the rule's choice (baseline $BASELINE_VIOLATIONS of 150 at $TAKEOVER; test only below $BASELINE_VIOLATIONS)"
  $PY -c "$PICK" $SWEEP "$TAKEOVER" $BASELINE_VIOLATIONS
fi
# follow-up (the note's "grid extended upwards", written after the first two rows): scales 1.1 and 1.05 on the same
# episodes, the choice over the four rows
SWEEP_UP=results/generalisation/mover-model-sweep-up-train2.json
JOINED=results/generalisation/mover-model-sweep-joined-train2.json
if [ "$STAGE" = up ]; then
  stamp "follow-up sweep on ugv-fields:train:2+ at scales 1.1 and 1.05, $EPISODES episodes a scale"
  [ -e $SWEEP_UP ] || $TIME $PY -m app.cli gate choose-scale $RUN --scenario ugv-fields:train:2+ --episodes $EPISODES \
      --scale 1.1 --scale 1.05 --violation-share 0 --takeover "$TAKEOVER" --out $SWEEP_UP
  $PY -c "import json, sys; rows = [r for f in sys.argv[2:] for r in json.load(open(f))['rows']]
json.dump({'rows': rows}, open(sys.argv[1], 'w'), indent=1)" $JOINED $SWEEP_UP $SWEEP
  stamp "the rule's choice over the four rows (baseline $BASELINE_VIOLATIONS of 150 at $TAKEOVER; test only below $BASELINE_VIOLATIONS)"
  $PY -c "import json, sys
for r in json.load(open(sys.argv[1]))['rows']:
    print('tau_scale %g: %d of %d, takeover %.1f%%' % (r['scale'], r['violations'], r['episodes'], 100 * r['takeover_rate']))" $JOINED
  $PY -c "$PICK" $JOINED "$TAKEOVER" $BASELINE_VIOLATIONS
  SWEEP=$JOINED
  STAGE=test
fi
if [ "$STAGE" = test ] || [ "$STAGE" = all ]; then
  SCALE=$($PY -c "$PICK" $SWEEP "$TAKEOVER" $BASELINE_VIOLATIONS)
  if [ "$SCALE" = none ]; then
    stamp "no scale passes the train check: nothing measured on test"
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

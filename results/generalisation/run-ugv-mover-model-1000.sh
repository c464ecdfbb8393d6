#!/bin/sh
# Issue 60: the mover model at gate.tau_scale=1.1 (runs/ugv-mover-model) against the committed gate, clause 1 at 1,000
# gate episodes on ugv-fields:test, and clause 6's built-in UGV gate rows (docs/notes/generalisation.md, "the mover
# model at gate.tau_scale=1.1: clause 1 taken to 1,000 episodes, and an added clause 6"). Stages: bounds, a (500 then
# 1,000 gate episodes for both gates), read (the first 300 and the 1,000), builtin (the candidate on the seven UGV rows
# of docs/calibration.md's gate table), builtin-base (the committed gate on the same rows, for comparison only);
# "all" runs them in that order. Run from the worktree's root.
# Usage: run-ugv-mover-model-1000.sh [STAGE]
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=${PY:-/work/main/.venv/bin/python}
STAGE=${1:-all}
RUN=runs/ugv-mover-model
SEEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml
GATE="--set gate.contact_horizon=10 --set gate.mover_model=cartesian"
BASE_CACHE=results/generalisation/ugv-1000.json
CAND_CACHE=results/generalisation/ugv-mover-model-1000.json
SCRATCH=results/generalisation/scratch-mover-model-1000.md
TIME="/usr/bin/time -f %e_s_wall_%U_s_user_%M_kB_peak"
stamp() { echo "== $(date -u +%FT%TZ) $*"; }
READ="$PY -m experiments.generalisation_rule --candidate $RUN --candidate-set gate.tau_scale=1.1 --candidate-cache $CAND_CACHE --baseline-cache $BASE_CACHE"

if [ "$STAGE" = bounds ] || [ "$STAGE" = all ]; then
  stamp "refit-bounds for gate.mover_model=cartesian, gate.contact_horizon=10, 50 drives a scenario"
  [ -e $RUN/checkpoint.pt ] || $TIME $PY -m app.cli gate refit-bounds policies/ugv-default --scenario $SEEN \
      $GATE --episodes 50 --out $RUN
fi
if [ "$STAGE" = a ] || [ "$STAGE" = all ]; then
  for N in 500 1000; do
    stamp "committed gate, ugv-fields:test, $N gate episodes (10 signal episodes)"
    $TIME $PY -m studies.generalisation --sim ugv --run policies/ugv-default --episodes 10 --gate-episodes $N \
        --grounds unseen --cache $BASE_CACHE --out $SCRATCH.base
    stamp "candidate at gate.tau_scale=1.1, ugv-fields:test, $N gate episodes (10 signal episodes)"
    $TIME $PY -m studies.generalisation --sim ugv --run $RUN --set gate.tau_scale=1.1 --episodes 10 \
        --gate-episodes $N --grounds unseen --cache $CAND_CACHE --out $SCRATCH
  done
fi
if [ "$STAGE" = read ] || [ "$STAGE" = all ]; then
  stamp "the first 300 (committed rows: 13 of 300 at 46%, 12 of 300 at 45%)"
  $READ --episodes 300
  stamp "the rule's reading at 1,000"
  $READ --episodes 1000
fi
ROWS="import json, sys, time
from pathlib import Path
import sims
from experiments.calibration import scenario_source, shown_scenario, table_scenarios
from studies.calibrate import gate_with_expert
run, out, settings = sys.argv[1], Path(sys.argv[2]), dict(a.split('=', 1) for a in sys.argv[3:])
settings = {k: float(v) for k, v in settings.items()}
d = sims.descriptor('ugv')
done = json.loads(out.read_text()) if out.is_file() else {}
for scenario in table_scenarios('ugv'):
    if scenario in done:
        continue
    source = scenario_source('ugv', scenario)
    started = time.perf_counter()
    point = gate_with_expert(run, lambda: d.make(source), 300, warn_steps=max(1, round(1.0 / d.dt)), **settings)
    point['seconds'] = time.perf_counter() - started
    done[scenario] = point
    out.write_text(json.dumps(done, indent=1))
    print('%s: %d/300 with a violation, takeover %.1f%% (%.0f s)' % (shown_scenario(scenario),
          round(point['violation_rate'] * 300), 100 * point['takeover_rate'], point['seconds']), flush=True)"
if [ "$STAGE" = builtin ] || [ "$STAGE" = all ]; then
  stamp "clause 6: the candidate on docs/calibration.md's UGV gate rows, 300 episodes a scenario"
  $TIME $PY -c "$ROWS" $RUN results/generalisation/mover-model-builtin-rows.json tau_scale=1.1
fi
if [ "$STAGE" = builtin-base ] || [ "$STAGE" = all ]; then
  stamp "the committed gate on the same rows (comparison with the table only)"
  $TIME $PY -c "$ROWS" policies/ugv-default results/generalisation/ugv-default-builtin-rows.json
fi
stamp done

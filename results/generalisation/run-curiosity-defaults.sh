#!/bin/sh
# Issue 60, target 3 (docs/notes/curiosity_defaults.md): curiosity that marks unseen ground, in the defaults.
# Stages: base SIM (the committed default's table at 300 + 300 into docs/generalisation.md), refit SIM, cand SIM (the
# candidate's table at 300 + 300, a scratch file), rows SIM RUN OUT (the built-in gate rows of docs/calibration.md,
# 300 episodes a scenario, the table's function and seeds).
# Usage: run-curiosity-defaults.sh STAGE SIM [RUN OUT]
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=${PY:-.venv/bin/python}
STAGE=$1
SIM=$2
RUN=runs/$SIM-curiosity
CACHE=results/generalisation/$SIM-curiosity.json
SCRATCH=results/generalisation/scratch-curiosity-$SIM.md
TIME="/usr/bin/time -f %e_s_wall_%U_s_user_%M_kB_peak"
stamp() { echo "== $(date -u +%FT%TZ) $* (at $(git rev-parse --short HEAD))"; }
case $SIM in
  pedestrian) SEEN=crossing,rare; SETS="--set gate.curiosity_signal=novelty --set gate.curiosity_reference=fitted" ;;
  highway) SEEN=train; SETS="--set gate.curiosity_signal=novelty --set gate.curiosity_reference=fitted" ;;
  ugv) SEEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml
       SETS="--set gate.curiosity_signal=disagreement --set gate.curiosity_reference=fitted" ;;
  *) SEEN=""; SETS="" ;;
esac
ROWS="import json, sys, time
from pathlib import Path
import sims
from experiments.calibration import scenario_source, shown_scenario, table_scenarios
from studies.calibrate import gate_with_expert
sim, run, out = sys.argv[1], sys.argv[2], Path(sys.argv[3])
d = sims.descriptor(sim)
done = json.loads(out.read_text()) if out.is_file() else {}
for scenario in table_scenarios(sim):
    if scenario in done:
        continue
    source = scenario_source(sim, scenario)
    started = time.perf_counter()
    point = gate_with_expert(run, lambda: d.make(source), 300, warn_steps=max(1, round(1.0 / d.dt)))
    point['seconds'] = time.perf_counter() - started
    done[scenario] = point
    out.write_text(json.dumps(done, indent=1))
    print('%s: %d/300 with a violation, takeover %.1f%% (%.0f s)' % (shown_scenario(scenario),
          round(point['violation_rate'] * 300), 100 * point['takeover_rate'], point['seconds']), flush=True)"

case $STAGE in
  base)
    stamp "$SIM: the committed default at 300 episodes a ground, 300 gate episodes"
    $TIME $PY -m studies.generalisation --sim $SIM --episodes 300 --gate-episodes 300 ;;
  refit)
    stamp "$SIM: refit-bounds on $SEEN with $SETS"
    [ -e $RUN/checkpoint.pt ] || $TIME $PY -m app.cli gate refit-bounds policies/$SIM-default --scenario $SEEN \
        $SETS --episodes 50 --out $RUN ;;
  cand)
    stamp "$SIM: the candidate at 300 episodes a ground, 300 gate episodes"
    $TIME $PY -m studies.generalisation --sim $SIM --run $RUN --episodes 300 --gate-episodes 300 --cache $CACHE \
        --out $SCRATCH ;;
  cand2)
    stamp "$SIM: the candidate on ugv-fields:test:2+, 100 episodes, 200 gate episodes"
    $TIME $PY -m studies.generalisation --sim $SIM --run $RUN --episodes 100 --gate-episodes 200 --grounds unseen \
        --unseen ugv-fields:test:2+ --cache $CACHE --out $SCRATCH.crowded ;;
  rows)
    stamp "$SIM: the built-in gate rows of $3 into $4"
    $TIME $PY -c "$ROWS" $SIM $3 $4 ;;
esac
stamp "done $STAGE $SIM"

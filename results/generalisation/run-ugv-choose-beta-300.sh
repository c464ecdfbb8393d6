#!/bin/sh
# Issue 60, the β-chosen-on-train candidate at the rule's size (docs/notes/generalisation.md): β and τ bounds from
# `sage gate refit-bounds --choose-beta` on DRIVES (default 50) drives of each training scenario and ugv-fields:train,
# then 300 unseen + 300 seen episodes (gate row at 300 each; the baseline's seeds), the rule's reading against the
# baseline's rows in docs/generalisation.md, and (a report, not the rule) the test fields with two or more movers.
# Each stage is stamped and timed (/usr/bin/time -v). Usage: run-ugv-choose-beta-300.sh [DRIVES]
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
DRIVES=${1:-50}
RUN=runs/ugv-choose-beta-$DRIVES
CACHE=results/generalisation/ugv-choose-beta-$DRIVES.json
SCRATCH=results/generalisation/scratch-choose-beta-$DRIVES.md
TRAIN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml,ugv-fields:train
SEEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml
TIME="/usr/bin/time -f %e_s_wall_%U_s_user_%M_kB_peak"
stamp() { echo "== $(date -u +%FT%TZ) $*"; }

stamp "refit-bounds, $DRIVES drives a scenario"
[ -e $RUN/checkpoint.pt ] || $TIME $PY -m app.cli gate refit-bounds policies/ugv-default --scenario $TRAIN \
    --episodes $DRIVES --choose-beta --out $RUN
stamp "unseen, 300 episodes (gate row 300)"
$TIME $PY -m studies.generalisation --sim ugv --run $RUN --episodes 300 --gate-episodes 300 --grounds unseen \
    --cache $CACHE --out $SCRATCH
stamp "seen, 300 episodes (gate row 300)"
$TIME $PY -m studies.generalisation --sim ugv --run $RUN --episodes 300 --gate-episodes 300 --grounds seen \
    --seen $SEEN --cache $CACHE --out $SCRATCH
stamp "table of both grounds, from the cache"
$PY -m studies.generalisation --sim ugv --run $RUN --episodes 300 --gate-episodes 300 --seen $SEEN --by-movers \
    --cached-only --cache $CACHE --out $SCRATCH
stamp "the rule's reading"
$PY -m experiments.generalisation_rule --candidate $RUN --candidate-cache $CACHE --episodes 300 --seen-episodes 300 \
    --baseline-table docs/generalisation.md
stamp "test fields with two or more movers, 100 episodes (gate row 200)"
$TIME $PY -m studies.generalisation --sim ugv --run $RUN --episodes 100 --gate-episodes 200 --grounds unseen \
    --unseen ugv-fields:test:2+ --cache $CACHE --out $SCRATCH.crowded
$PY -m experiments.generalisation_rule --candidate $RUN --candidate-cache $CACHE --unseen ugv-fields:test:2+ \
    --episodes 200 --baseline-table docs/generalisation.md
stamp done

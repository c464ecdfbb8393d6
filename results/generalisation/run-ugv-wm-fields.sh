#!/bin/sh
# Issue 60 part 2: a world model refitted on ugv-fields:train (results/generalisation/refit-fields.sh) measured as the
# baseline was (results/generalisation/run-ugv-300.sh): the unseen ground, then the seen ground given as the
# baseline's four built-in scenarios (same seeds), then the rule's reading against the baseline's cached rows.
# Usage: run-ugv-wm-fields.sh RUN UNSEEN_EPISODES SEEN_EPISODES
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
RUN=$1
N=${2:-100}
S=${3:-120}
CACHE=results/generalisation/ugv-wm-fields.json
SEEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml
OUT=results/generalisation/scratch-wm-fields-$(basename "$RUN")-$N.md
$PY -m studies.generalisation --sim ugv --run "$RUN" --episodes "$N" --gate-episodes "$N" --grounds unseen \
    --cache $CACHE --out "$OUT"
$PY -m studies.generalisation --sim ugv --run "$RUN" --episodes "$S" --gate-episodes "$S" --grounds seen \
    --seen $SEEN --cache $CACHE --out "$OUT.seen"
$PY -m experiments.generalisation_rule --candidate "$RUN" --candidate-cache $CACHE --episodes "$N" --seen-episodes "$S"

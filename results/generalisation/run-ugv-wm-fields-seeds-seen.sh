#!/bin/sh
# The refits of seeds 1 and 2 on the seen ground (the baseline's four scenarios, its seeds), 120 episodes, and the rule.
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
CACHE=results/generalisation/ugv-wm-fields-seeds.json
SEEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml
for seed in 1 2; do
    $PY -m studies.generalisation --sim ugv --run runs/wm-fields-s$seed --episodes 120 --gate-episodes 120 \
        --grounds seen --seen $SEEN --cache $CACHE --out results/generalisation/scratch-wm-fields-s$seed-100.md.seen
    $PY -m experiments.generalisation_rule --candidate runs/wm-fields-s$seed --candidate-cache $CACHE --episodes 100 \
        --seen-episodes 120
done

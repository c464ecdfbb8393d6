#!/bin/sh
# The refits of seeds 1 and 2 (results/generalisation/refit-fields-seeds.sh) on the unseen ground, 100 episodes (the
# signals for fear AUROC's spread over three refit seeds, and the gate row), as soon as each refit has finished.
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
CACHE=results/generalisation/ugv-wm-fields-seeds.json
for seed in 1 2; do
    until grep -q "Exit status" results/generalisation/refit-fields-s$seed.log 2>/dev/null; do sleep 10; done
    $PY -m studies.generalisation --sim ugv --run runs/wm-fields-s$seed --episodes 100 --gate-episodes 100 \
        --grounds unseen --cache $CACHE --out results/generalisation/scratch-wm-fields-s$seed-100.md
    $PY -m experiments.generalisation_rule --candidate runs/wm-fields-s$seed --candidate-cache $CACHE --episodes 100
done

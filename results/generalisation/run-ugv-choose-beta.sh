#!/bin/sh
# Issue 60, a candidate the ablation suggests (exploratory pilot): β chosen on train ground only (the committed
# policy's four training scenarios and ugv-fields:train, 20 drives each, `sage gate refit-bounds --choose-beta`), its τ
# bounds measured on the same drives, then 100 episodes of ugv-fields:test against the baseline's first 100.
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
SCEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml,ugv-fields:train
CACHE=results/generalisation/ugv-choose-beta.json
$PY -m app.cli gate refit-bounds policies/ugv-default --scenario $SCEN --episodes 20 --choose-beta \
    --out runs/ugv-choose-beta
$PY -m studies.generalisation --sim ugv --run runs/ugv-choose-beta --episodes 100 --gate-episodes 100 \
    --grounds unseen --cache $CACHE --out results/generalisation/scratch-choose-beta.md
$PY -m experiments.generalisation_rule --candidate runs/ugv-choose-beta --candidate-cache $CACHE --episodes 100

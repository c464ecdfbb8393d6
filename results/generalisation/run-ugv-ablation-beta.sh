#!/bin/sh
# Issue 60, exploratory ablation: which part of fear carries to unseen ground? The committed UGV gate with fear on σ̂
# alone (gate.beta=0) and on ĉ alone (gate.beta=1): τ bounds measured again for each on the policy's own training
# scenarios (25 drives each, where the committed bounds took 100: a smaller sample), then 100 episodes of
# ugv-fields:test against the baseline's first 100 (same seeds).
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
SCEN=1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml
CACHE=results/generalisation/ugv-ablation-beta.json
for beta in 0 1; do
    $PY -m app.cli gate refit-bounds policies/ugv-default --scenario $SCEN --episodes 25 --set gate.beta=$beta \
        --out runs/ugv-beta$beta
    $PY -m studies.generalisation --sim ugv --run runs/ugv-beta$beta --episodes 100 --gate-episodes 100 \
        --grounds unseen --cache $CACHE --out results/generalisation/scratch-ablation-beta$beta.md
    $PY -m experiments.generalisation_rule --candidate runs/ugv-beta$beta --candidate-cache $CACHE --episodes 100
done

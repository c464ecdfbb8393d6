#!/bin/sh
# Issue 60 part 2, first lever: refit only the world model of policies/ugv-default on ugv-fields:train plus its own
# training scenarios (1, 2, clutter, movers), the settings of policies/ugv-default/README.md's movers/ego refit, at a
# smaller size (the 2-core machine's budget). Usage: refit-fields.sh SEED [EPISODES] [DEMO_EPISODES]
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
SEED=${1:-0}
EPISODES=${2:-100}
DEMOS=${3:-80}
$PY -m app.cli train --sim ugv \
    --scenario ugv-fields:train,1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml --method sac \
    --episodes "$EPISODES" --seed "$SEED" --init policies/ugv-default --world-model-only \
    --demo-episodes "$DEMOS" --demo-noise 0.3 \
    --set env.expert.yield_to_movers=false --set world_model_config.violation_steps=20 \
    --set world_model_config.cost_label_weight=0.3 --set gate.release=1 \
    --checkpoint-every 0 --checkpoint-dtype float16 --quiet --out "runs/wm-fields-s$SEED"

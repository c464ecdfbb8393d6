#!/bin/bash
# Why FNI-RL beats SAGE alone at 30,000 steps (#62), third probe: SAGE with both the expert's takeover and the
# imitation off (`learner.takeover=false learner.imitation=false`: FNI-RL's switches but curiosity, which only moves
# the threshold of a takeover that no longer happens), seeds 0 and 1 at once (SEEDS="2 3" for the next two), the
# study's trial protocol, then alone on 10 episodes of each route with the study's evaluation seed. Rule in
# docs/notes/route_shift_budget.md ("Third probe"), written before this run.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/../.."
one() {
  local seed=$1
  echo "== seed $seed start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  nice -n 5 .venv/bin/python -m app.cli train --sim sumo --protocol route-shift --method sage --seed $seed \
    --train-steps 30000 --c1-share 0.6666666666666666 --demo-episodes 5 --demo-steps 15000 --checkpoint-every 0 \
    --set learner.takeover=false --set learner.imitation=false --quiet --out results/route-shift-probe/runs/sage-neither-s$seed
  echo "== seed $seed rc=$? end $(date -u +%FT%T)"
  nice -n 5 .venv/bin/python -m app.cli eval results/route-shift-probe/runs/sage-neither-s$seed \
    --scenario c1,c2 --episodes 10 --seed $seed --quiet
}
for seed in ${SEEDS:-0 1}; do one $seed > results/route-shift-probe/neither-s$seed.log 2>&1 & done
wait

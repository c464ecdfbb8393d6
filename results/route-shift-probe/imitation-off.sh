#!/bin/bash
# Why FNI-RL beats SAGE alone at 30,000 steps on the route shift (#62): SAGE with its value-weighted imitation off,
# seeds 0 and 1, the route-shift study's own trial protocol (as the pilot in docs/notes/route_shift_budget.md).
# Rule in that note, section "Why FNI-RL drives route 1 alone and SAGE does not", written before this run.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/../.."
for seed in 0 1; do
  echo "== seed $seed start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  nice -n 5 .venv/bin/python -m app.cli train --sim sumo --protocol route-shift --method sage --seed $seed \
    --train-steps 30000 --c1-share 0.6666666666666666 --demo-episodes 5 --demo-steps 15000 --checkpoint-every 0 \
    --set learner.imitation=false --out results/route-shift-probe/runs/sage-noimitation-s$seed
  echo "== rc=$? end $(date -u +%FT%T)"
  nice -n 5 .venv/bin/python -m app.cli eval results/route-shift-probe/runs/sage-noimitation-s$seed \
    --scenario c1,c2 --episodes 10 --seed $seed --quiet
done

#!/bin/bash
# The pilot of docs/notes/route_shift_budget.md: seed 0, SAC then SAGE, 30,000 environment steps each.
set -u
export OMP_NUM_THREADS=1
PY=/work/main/.venv/bin/python
OUT=results/route-shift-pilot-30k
for M in sac sage; do
  echo "== $M start $(date -u +%FT%T)"
  start=$(date +%s)
  $PY -m app.cli train --sim sumo --protocol route-shift --method $M --seed 0 --train-steps 30000 \
    --c1-share 0.6666666666666666 --demo-episodes 5 --demo-steps 15000 --checkpoint-every 0 --out $OUT/runs/$M-s0
  echo "== $M rc=$? wall_s=$(( $(date +%s) - start )) end $(date -u +%FT%T)"
done
$PY -m app.cli figure route-shift $OUT/runs/sac-s0 $OUT/runs/sage-s0 --out $OUT

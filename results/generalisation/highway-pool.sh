#!/usr/bin/env bash
# Issue 60, twenty-third session (2026-11-30): one highway gate over the committed world model and two approach-rate
# refits (runs/highway-approach-sA, -sB) merged, measured by the approach rule's stage B. Plan and rule in
# docs/notes/generalisation.md ("Twenty-third session: the pooled highway gate, measured"), written before this run.
#   Usage: bash highway-pool.sh A B
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1
PY=.venv/bin/python
A=$1
B=$2
pool=runs/highway-pool-$A$B
run=runs/highway-pool-$A$B-bounds
out=results/generalisation
log=$out/highway-pool-$A$B.log
choice=$out/highway-pool-$A$B-scale.json
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): merge refits $A and $B with the committed model"
  [ -f "$pool/checkpoint.pt" ] || .venv/bin/sage gate merge runs/highway-approach-s$A runs/highway-approach-s$B \
      policies/highway-default --out "$pool"
  echo "== $(date -u +%H:%M:%S): refit-bounds on train ground"
  [ -f "$run/checkpoint.pt" ] || .venv/bin/sage gate refit-bounds "$pool" --scenario train,train-adversarial \
      --episodes 100 --out "$run"
  echo "== $(date -u +%H:%M:%S): choose-scale on train, train-adversarial"
  [ -f "$choice" ] || .venv/bin/sage gate choose-scale "$run" --sim highway --scenario train \
      --scenario train-adversarial --episodes 100 --out "$choice"
  scale=$($PY -c "import json; print(json.load(open('$choice'))['scale'])")
  echo "== $(date -u +%H:%M:%S): scale $scale; generalisation tables, 300 + 300"
  $PY -m studies.generalisation --sim highway --run "$run" --episodes 300 --gate-episodes 300 \
      --set gate.tau_scale="$scale" --out $out/highway-pool-$A$B.md --cache $out/highway-pool-$A$B.json
  echo "== $(date -u +%H:%M:%S): the rule's reading against step 10's committed rows"
  $PY -m experiments.generalisation_rule --sim highway --candidate "$run" \
      --candidate-cache $out/highway-pool-$A$B.json --candidate-set gate.tau_scale="$scale" \
      --baseline policies/highway-default --baseline-table docs/generalisation.md \
      --unseen highway-shift:test --seen train --episodes 300 --seen-episodes 300
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a "$log"

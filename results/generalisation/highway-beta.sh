#!/usr/bin/env bash
# Issue 60, nineteenth session (2026-11-30): highway's β (fear = (1 - β) σ̂ + β ĉ's mix) and operating point chosen on
# train ground, measured on highway-shift:test. Plan and rule in docs/notes/generalisation.md ("Nineteenth session:
# highway's β chosen on train ground"), written before this run.
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
run=runs/highway-beta
log=results/generalisation/highway-beta.log
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): refit-bounds --choose-beta on train ground"
  .venv/bin/sage gate refit-bounds policies/highway-default --scenario train,train-adversarial,highway-shift:train \
      --episodes 100 --choose-beta --checkpoint-dtype float16 --out "$run"
  echo "== $(date -u +%H:%M:%S): choose-scale on train, train-adversarial (the committed choice's grid and episodes)"
  .venv/bin/sage gate choose-scale "$run" --sim highway --scenario train --scenario train-adversarial \
      --episodes 100 --out results/generalisation/highway-beta-scale.json
  scale=$($PY -c "import json; print(json.load(open('results/generalisation/highway-beta-scale.json'))['scale'])")
  echo "== $(date -u +%H:%M:%S): chosen scale $scale; generalisation tables, 300 + 300"
  $PY -m studies.generalisation --sim highway --run "$run" --episodes 300 --gate-episodes 300 \
      --set gate.tau_scale="$scale" --out results/generalisation/highway-beta.md \
      --cache results/generalisation/highway-beta.json
  echo "== $(date -u +%H:%M:%S): the rule's reading against the committed rows"
  $PY -m experiments.generalisation_rule --sim highway --candidate "$run" --candidate-cache results/generalisation/highway-beta.json \
      --candidate-set gate.tau_scale="$scale" --baseline policies/highway-default --baseline-table docs/generalisation.md \
      --unseen highway-shift:test --seen train --episodes 300 --seen-episodes 300
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a "$log"

#!/usr/bin/env bash
# Issue 60, twentieth session (2026-11-30): highway's world model refitted on train, train-adversarial and
# highway-shift:train (three refit seeds), measured on highway-shift:test. Plan and rule in
# docs/notes/generalisation.md ("Twentieth session: highway's world model refitted on highway-shift:train"), written
# before this run.   Usage: bash highway-wm-shift.sh SEED
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
S=$1
fit=runs/highway-wm-shift-s$S
run=runs/highway-wm-shift-s$S-bounds
log=results/generalisation/highway-wm-shift-s$S.log
choice=results/generalisation/highway-wm-shift-s$S-scale.json
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): seed $S world-model refit"
  .venv/bin/sage train --sim highway --scenario train,train-adversarial,highway-shift:train \
      --init policies/highway-default --world-model-only --episodes 300 --demo-episodes 20 --demo-noise 0.3 \
      --seed "$S" --checkpoint-every 0 --checkpoint-dtype float16 --quiet --out "$fit"
  echo "== $(date -u +%H:%M:%S): refit-bounds on train ground"
  .venv/bin/sage gate refit-bounds "$fit" --scenario train,train-adversarial,highway-shift:train \
      --episodes 100 --checkpoint-dtype float16 --out "$run"
  echo "== $(date -u +%H:%M:%S): choose-scale on train, train-adversarial"
  .venv/bin/sage gate choose-scale "$run" --sim highway --scenario train --scenario train-adversarial \
      --episodes 100 --out "$choice"
  scale=$($PY -c "import json; print(json.load(open('$choice'))['scale'])")
  echo "== $(date -u +%H:%M:%S): scale $scale; generalisation tables, 300 + 300"
  $PY -m studies.generalisation --sim highway --run "$run" --episodes 300 --gate-episodes 300 \
      --set gate.tau_scale="$scale" --out results/generalisation/highway-wm-shift-s$S.md \
      --cache results/generalisation/highway-wm-shift-s$S.json
  echo "== $(date -u +%H:%M:%S): the rule's reading against step 10's committed rows"
  $PY -m experiments.generalisation_rule --sim highway --candidate "$run" \
      --candidate-cache results/generalisation/highway-wm-shift-s$S.json --candidate-set gate.tau_scale="$scale" \
      --baseline policies/highway-default --baseline-table docs/generalisation.md \
      --unseen highway-shift:test --seen train --episodes 300 --seen-episodes 300
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a "$log"

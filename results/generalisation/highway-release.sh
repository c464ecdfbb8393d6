#!/usr/bin/env bash
# Issue 60, nineteenth session (later): highway's default without the hysteresis (gate.release=0), its operating point
# chosen again on train ground. Plan and rule in docs/notes/generalisation.md ("Nineteenth session, later"), written
# before this run.
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
log=results/generalisation/highway-release.log
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): choose-scale with gate.release=0 on train ground"
  .venv/bin/sage gate choose-scale policies/highway-default --sim highway --scenario train \
      --scenario train-adversarial --episodes 100 --set gate.release=0 \
      --out results/generalisation/highway-release-scale.json
  scale=$($PY -c "import json; print(json.load(open('results/generalisation/highway-release-scale.json'))['scale'])")
  echo "== $(date -u +%H:%M:%S): chosen scale $scale; generalisation tables and built-in rows"
  $PY -m studies.generalisation --sim highway --episodes 300 --gate-episodes 300 --set gate.release=0 \
      --set gate.tau_scale="$scale" --out results/generalisation/highway-release.md \
      --cache results/generalisation/highway-release.json &
  $PY results/generalisation/builtin_rows.py highway policies/highway-default \
      results/generalisation/highway-release-builtin-rows.json release=0 tau_scale="$scale" &
  wait
  echo "== $(date -u +%H:%M:%S): the rule's reading against step 9's default"
  $PY -m experiments.generalisation_rule --sim highway --candidate policies/highway-default \
      --candidate-cache results/generalisation/highway-release.json --candidate-set gate.release=0 \
      --candidate-set gate.tau_scale="$scale" --baseline policies/highway-default \
      --baseline-table docs/generalisation.md --unseen highway-shift:test --seen train --episodes 300 \
      --seen-episodes 300
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a "$log"

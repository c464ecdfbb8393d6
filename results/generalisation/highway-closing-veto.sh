#!/usr/bin/env bash
# Issue 60, twenty-first session (2026-11-30): fear over τ hands over only where the real observations show something
# closing (gate.closing_veto). Plan and rule in docs/notes/generalisation.md ("Twenty-first session: fear withheld
# where nothing observed closes"), written before this run.
# Stage A (train ground):  bash highway-closing-veto.sh A        (T = 3, 5, 8 s, one after another)
# Stage B (once, T chosen): bash highway-closing-veto.sh B T      (generalisation tables and the rule's reading)
# Stage C (once, T chosen): bash highway-closing-veto.sh C T      (docs/calibration.md's five built-in rows, both gates)
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
stage=$1
out=results/generalisation
log=$out/highway-closing-veto.log
{
if [ "$stage" = A ]; then
  for T in 3 5 8; do
    echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T choose-scale (scale 1) on train, train-adversarial"
    .venv/bin/sage gate choose-scale policies/highway-default --scenario train --scenario train-adversarial \
        --episodes 100 --scale 1 --set gate.closing_veto=$T --out "$out/highway-closing-veto-t$T-train.json"
  done
  echo "== $(date -u +%H:%M:%S): stage A done"
elif [ "$stage" = B ]; then
  T=$2
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T generalisation tables, 300 + 300"
  $PY -m studies.generalisation --sim highway --episodes 300 --gate-episodes 300 --set gate.closing_veto="$T" \
      --out $out/highway-closing-veto.md --cache $out/highway-closing-veto.json
  echo "== $(date -u +%H:%M:%S): the rule's reading against step 10's committed rows"
  $PY -m experiments.generalisation_rule --sim highway --candidate policies/highway-default \
      --candidate-cache $out/highway-closing-veto.json --candidate-set gate.closing_veto="$T" \
      --baseline policies/highway-default --baseline-table docs/generalisation.md \
      --unseen highway-shift:test --seen train --episodes 300 --seen-episodes 300
  echo "== $(date -u +%H:%M:%S): stage B done"
else
  T=$2
  floors=$($PY -c "import json, sims; print(json.dumps(list(sims.descriptor('highway').contact_floors)))")
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T built-in rows, candidate then committed"
  $PY $out/builtin_rows.py highway policies/highway-default $out/highway-closing-veto-builtin.json \
      closing_veto="$T" contact_floors="$floors"
  $PY $out/builtin_rows.py highway policies/highway-default $out/highway-closing-veto-builtin-baseline.json
  echo "== $(date -u +%H:%M:%S): stage C done"
fi
} 2>&1 | tee -a "$log"

#!/usr/bin/env bash
# Issue 60, twentieth session (2026-11-30): the observed closing of the car ahead or behind in highway's fear (imagined
# contact on the lane beams, extrapolated at the closing the real scans show). Plan and rule in
# docs/notes/generalisation.md ("Twentieth session: the observed closing ..."), written before this run.
# Stage A (train ground): bash highway-lane-contact.sh A H   (H in 10 20 30)
# Stage B (test, once):   bash highway-lane-contact.sh B H
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
stage=$1
H=$2
run=runs/highway-lane-contact-h$H
sets=(--set gate.imagined_contact=true --set gate.contact_extrapolation=true --set gate.contact_horizon=$H)
log=results/generalisation/highway-lane-contact-h$H.log
choice=results/generalisation/highway-lane-contact-h$H-scale.json
{
if [ "$stage" = A ]; then
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): H=$H refit-bounds on train ground"
  .venv/bin/sage gate refit-bounds policies/highway-default --scenario train,train-adversarial,highway-shift:train \
      --episodes 100 "${sets[@]}" --checkpoint-dtype float16 --out "$run"
  echo "== $(date -u +%H:%M:%S): choose-scale on train, train-adversarial"
  .venv/bin/sage gate choose-scale "$run" --sim highway --scenario train --scenario train-adversarial \
      --episodes 100 --out "$choice"
  echo "== $(date -u +%H:%M:%S): stage A done"
else
  scale=$($PY -c "import json; print(json.load(open('$choice'))['scale'])")
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): H=$H scale $scale; generalisation tables, 300 + 300"
  $PY -m studies.generalisation --sim highway --run "$run" --episodes 300 --gate-episodes 300 \
      --set gate.tau_scale="$scale" --out results/generalisation/highway-lane-contact.md \
      --cache results/generalisation/highway-lane-contact.json
  echo "== $(date -u +%H:%M:%S): the rule's reading against step 10's committed rows"
  $PY -m experiments.generalisation_rule --sim highway --candidate "$run" \
      --candidate-cache results/generalisation/highway-lane-contact.json --candidate-set gate.tau_scale="$scale" \
      --baseline policies/highway-default --baseline-table docs/generalisation.md \
      --unseen highway-shift:test --seen train --episodes 300 --seen-episodes 300
  echo "== $(date -u +%H:%M:%S): done"
fi
} 2>&1 | tee -a "$log"

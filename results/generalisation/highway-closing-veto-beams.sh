#!/usr/bin/env bash
# Issue 60, twenty-first session: candidate 2 of the closing veto, every beam with the ego's body outline as its floor
# (the amendment in docs/notes/generalisation.md, written after the lane-beam stage A, before this run).
# Stage A: bash highway-closing-veto-beams.sh A ; stage B: ... B T ; stage C: ... C T
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
stage=$1
out=results/generalisation
log=$out/highway-closing-veto-beams.log
floors=$($PY - <<'PYEOF'
import math
from sims.highway.config import HighwayConfig
from sims.highway.env import OBS_SIZE
c = HighwayConfig(); beams = c.sensor.beams
edges = []
for i in range(beams):
    t = 2 * math.pi * i / beams
    cs, sn = abs(math.cos(t)), abs(math.sin(t))
    edges.append(min(c.ego.length / 2 / cs if cs > 1e-12 else math.inf, c.ego.width / 2 / sn if sn > 1e-12 else math.inf))
print("[" + ",".join(["none"] * (OBS_SIZE - beams) + [f"{e / c.sensor.range:.6f}" for e in edges]) + "]")
PYEOF
)
{
if [ "$stage" = A ]; then
  for T in 3 5 8; do
    echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T every beam, choose-scale (scale 1) on train, train-adversarial"
    .venv/bin/sage gate choose-scale policies/highway-default --scenario train --scenario train-adversarial \
        --episodes 100 --scale 1 --set gate.closing_veto=$T --set gate.contact_floors="$floors" \
        --out "$out/highway-closing-veto-beams-t$T-train.json"
  done
  echo "== $(date -u +%H:%M:%S): stage A done"
elif [ "$stage" = B ]; then
  T=$2
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T every beam, generalisation tables, 300 + 300"
  $PY -m studies.generalisation --sim highway --episodes 300 --gate-episodes 300 --set gate.closing_veto="$T" \
      --set gate.contact_floors="$floors" --out $out/highway-closing-veto-beams.md --cache $out/highway-closing-veto-beams.json
  $PY -m experiments.generalisation_rule --sim highway --candidate policies/highway-default \
      --candidate-cache $out/highway-closing-veto-beams.json --candidate-set gate.closing_veto="$T" \
      --candidate-set gate.contact_floors="$floors" \
      --baseline policies/highway-default --baseline-table docs/generalisation.md \
      --unseen highway-shift:test --seen train --episodes 300 --seen-episodes 300
  echo "== $(date -u +%H:%M:%S): stage B done"
else
  T=$2
  json=$(echo "$floors" | sed 's/none/null/g')
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T every beam, built-in rows, candidate then committed"
  $PY $out/builtin_rows.py highway policies/highway-default $out/highway-closing-veto-beams-builtin.json \
      closing_veto="$T" contact_floors="$json"
  $PY $out/builtin_rows.py highway policies/highway-default $out/highway-closing-veto-builtin-baseline.json
  echo "== $(date -u +%H:%M:%S): stage C done"
fi
} 2>&1 | tee -a "$log"

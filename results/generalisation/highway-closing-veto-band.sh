#!/usr/bin/env bash
# Issue 60, twenty-first session: candidate 3 of the closing veto, the beams within the ego's band with its bumper line
# as their floor (docs/notes/generalisation.md, "Candidate 3 on highway", written before this run). Stage C compares
# with the committed gate's rows measured by highway-closing-veto-beams.sh C (highway-closing-veto-builtin-baseline).
# Stage A: bash highway-closing-veto-band.sh A ; stage B: ... B T ; stage C: ... C T
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
stage=$1
out=results/generalisation
log=$out/highway-closing-veto-band.log
floors=$($PY - <<'PYEOF'
import math
from sims.highway.config import HighwayConfig
from sims.highway.env import OBS_SIZE
c = HighwayConfig(); beams = c.sensor.beams
edges = []
for i in range(beams):
    t = 2 * math.pi * i / beams
    cs, sn = abs(math.cos(t)), abs(math.sin(t))
    # the bumper line's distance along the beam, on the beams whose point there lies within the ego's band
    edges.append(c.ego.length / 2 / cs if cs > 1e-12 and sn / cs < (c.ego.width / 2 + 0.3 + 1.0) / (c.ego.length / 2) else None)
print("[" + ",".join(["none"] * (OBS_SIZE - beams) + ["none" if e is None else f"{e / c.sensor.range:.6f}" for e in edges]) + "]")
PYEOF
)
{
if [ "$stage" = A ]; then
  for T in 3 5 8; do
    echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T the band, choose-scale (scale 1) on train, train-adversarial"
    .venv/bin/sage gate choose-scale policies/highway-default --scenario train --scenario train-adversarial \
        --episodes 100 --scale 1 --set gate.closing_veto=$T --set gate.contact_floors="$floors" \
        --out "$out/highway-closing-veto-band-t$T-train.json"
  done
  echo "== $(date -u +%H:%M:%S): stage A done"
elif [ "$stage" = B ]; then
  T=$2
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T the band, generalisation tables, 300 + 300"
  $PY -m studies.generalisation --sim highway --episodes 300 --gate-episodes 300 --set gate.closing_veto="$T" \
      --set gate.contact_floors="$floors" --out $out/highway-closing-veto-band.md --cache $out/highway-closing-veto-band.json
  $PY -m experiments.generalisation_rule --sim highway --candidate policies/highway-default \
      --candidate-cache $out/highway-closing-veto-band.json --candidate-set gate.closing_veto="$T" \
      --candidate-set gate.contact_floors="$floors" \
      --baseline policies/highway-default --baseline-table docs/generalisation.md \
      --unseen highway-shift:test --seen train --episodes 300 --seen-episodes 300
  echo "== $(date -u +%H:%M:%S): stage B done"
else
  T=$2
  json=$(echo "$floors" | sed 's/none/null/g')
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T the band, built-in rows, candidate then committed"
  $PY $out/builtin_rows.py highway policies/highway-default $out/highway-closing-veto-band-builtin.json \
      closing_veto="$T" contact_floors="$json"
  echo "== $(date -u +%H:%M:%S): stage C done"
fi
} 2>&1 | tee -a "$log"

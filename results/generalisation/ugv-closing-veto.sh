#!/usr/bin/env bash
# Issue 60, twenty-first session: the closing veto on the UGV (gate.closing_veto over the 54 sectors' footprint floors,
# which the committed gate already declares). Rule in docs/notes/generalisation.md ("The same veto on the UGV"),
# written before this run.
# Stage A: bash ugv-closing-veto.sh A ; stage B: ... B T ; stage C (built-in rows): ... C T
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
stage=$1
out=results/generalisation
log=$out/ugv-closing-veto.log
{
if [ "$stage" = A ]; then
  for T in 1 2 3; do
    echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T choose-scale (scale 1.1) on ugv-fields:train:2+"
    .venv/bin/sage gate choose-scale policies/ugv-default --scenario ugv-fields:train:2+ --episodes 150 --scale 1.1 \
        --set gate.closing_veto=$T --out "$out/ugv-closing-veto-t$T-train2.json"
  done
  echo "== $(date -u +%H:%M:%S): stage A done"
elif [ "$stage" = B ]; then
  T=$2
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T the 2+ ground, 100 + 200"
  $PY -m studies.generalisation --sim ugv --episodes 100 --gate-episodes 200 --grounds unseen \
      --unseen ugv-fields:test:2+ --set gate.closing_veto="$T" --out $out/ugv-closing-veto-2plus.md \
      --cache $out/ugv-closing-veto-2plus.json
  echo "== $(date -u +%H:%M:%S): T=$T generalisation tables, 300 + 300"
  $PY -m studies.generalisation --sim ugv --episodes 300 --gate-episodes 300 --set gate.closing_veto="$T" \
      --out $out/ugv-closing-veto.md --cache $out/ugv-closing-veto.json
  $PY -m experiments.generalisation_rule --sim ugv --candidate policies/ugv-default \
      --candidate-cache $out/ugv-closing-veto.json --candidate-set gate.closing_veto="$T" \
      --baseline policies/ugv-default --baseline-table docs/generalisation.md --episodes 300 --seen-episodes 300
  echo "== $(date -u +%H:%M:%S): stage B done"
else
  T=$2
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): T=$T built-in rows, the candidate"
  $PY $out/builtin_rows.py ugv policies/ugv-default $out/ugv-closing-veto-builtin.json closing_veto="$T"
  echo "== $(date -u +%H:%M:%S): stage C done"
fi
} 2>&1 | tee -a "$log"

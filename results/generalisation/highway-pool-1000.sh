#!/usr/bin/env bash
# Issue 60, twenty-third session: clause 6's path for the pooled highway gate (docs/notes/generalisation.md,
# "Amendment (written 21:24 UTC ...)"): a gate driven to 1,000 unseen gate episodes on the table's seeds.
#   Usage: bash highway-pool-1000.sh committed | POOL (e.g. 01) SCALE
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1
PY=.venv/bin/python
out=results/generalisation
if [ "$1" = committed ]; then
  run=policies/highway-default; cache=$out/highway-committed-1000.json; extra=(); name=committed
else
  run=runs/highway-pool-$1-bounds; cache=$out/highway-pool-$1-1000.json; extra=(--set gate.tau_scale="$2"); name=pool-$1
fi
log=$out/highway-1000-$name.log
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): $run to 1,000 unseen gate episodes"
  $PY -m studies.generalisation --sim highway --run "$run" --grounds unseen --episodes 10 --gate-episodes 1000 \
      "${extra[@]}" --out $out/highway-1000-$name.md --cache "$cache"
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a "$log"

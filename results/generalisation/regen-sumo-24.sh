#!/usr/bin/env bash
# docs/generalisation.md's SUMO section made again for the adopted default (twenty-fourth session): both grounds at
# once on two cores into two caches, then the table written from them (the same episodes and seeds as one run).
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
export OMP_NUM_THREADS=1
out=results/generalisation
log=$out/regen-sumo-24.log
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD)"
  $PY -m studies.generalisation --sim sumo --episodes 300 --gate-episodes 300 --grounds unseen \
      --out $out/regen24-sumo-unseen.md --cache $out/regen24-sumo-unseen.json &
  $PY -m studies.generalisation --sim sumo --episodes 300 --gate-episodes 300 --grounds seen \
      --out $out/regen24-sumo-seen.md --cache $out/regen24-sumo-seen.json &
  wait
  $PY -c "import json; a = json.load(open('$out/regen24-sumo-unseen.json')); a.update(json.load(open('$out/regen24-sumo-seen.json'))); json.dump(a, open('$out/regen24-sumo.json', 'w'))"
  $PY -m studies.generalisation --sim sumo --episodes 300 --gate-episodes 300 --cached-only \
      --cache $out/regen24-sumo.json
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a "$log"

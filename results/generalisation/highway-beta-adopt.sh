#!/usr/bin/env bash
# Issue 60, nineteenth session: highway's β chosen on train ground passed the rule (docs/notes/generalisation.md,
# "Nineteenth session: highway's β chosen on train ground"), so it becomes policies/highway-default (step 9 of its
# README). The deploy (a 0-episode run: every tensor equal, only gate.tau_scale written) was run by hand at 12:18 UTC:
#   sage train --sim highway --scenario train --init runs/highway-beta --world-model-only --episodes 0 \
#       --demo-episodes 0 --seed 2 --set gate.tau_scale=1 --checkpoint-every 0 --checkpoint-dtype float16 \
#       --quiet --out runs/highway-beta-deploy   # checkpoint.pt and config.json copied into policies/highway-default
# This script regenerates the documents that describe the committed default.
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
log=results/generalisation/highway-beta-adopt.log
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): the generalisation table of the new default"
  $PY -m studies.generalisation --sim highway --episodes 300 --gate-episodes 300 &
  echo "== $(date -u +%H:%M:%S): its built-in gate rows (docs/calibration.md's scenarios and seeds)"
  $PY results/generalisation/builtin_rows.py highway policies/highway-default \
      results/generalisation/highway-default-beta-builtin-rows.json &
  wait
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a "$log"

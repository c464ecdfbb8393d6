#!/bin/bash
# Twenty-third session: the UGV's hysteresis (gate.release=0) on unseen ground, a scratch probe; reading in
# docs/notes/generalisation.md ("the UGV's hysteresis on unseen ground"), written before the run.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/../.."
for arm in committed release0; do
  extra=()
  [ "$arm" = release0 ] && extra=(--set gate.release=0)
  echo "== $arm start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  .venv/bin/python -m studies.generalisation --sim ugv --grounds unseen --episodes 20 --gate-episodes 100 "${extra[@]}" \
    --out results/generalisation/ugv-release-probe-$arm.md --cache results/generalisation/ugv-release-probe-$arm.json
  echo "== $arm rc=$? end $(date -u +%FT%T)"
done

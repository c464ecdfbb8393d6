#!/bin/bash
# Issue 63 ("every study table states its wall time and the device") and issue 60 (the generalisation tables), twenty-
# second session (2026-11-30): docs/generalisation.md's sections were made at 7c08b8f / 399c47b / 26b2c1e / bee4cf4,
# before its header named the processor and the command's wall time. Made again from fresh caches at this commit, on
# this session's host (Intel Xeon, 2 cores), the defaults as committed (no default has changed since those commits).
# Two chains side by side (so each wall time is beside one other command): A = pedestrian then sumo;
# B = highway, then ugv (with --by-movers), then the UGV two-mover ground and its subsection.
# Reading, written before the run: every row is measured on the seeds of the committed one (the study's seeds), so a
# row should reproduce; a row that differs is reported with its difference (the code since those commits and the
# processor kind are the only changes), and the README summary follows the document.   Usage: bash ... A|B
set -u
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
out=results/generalisation
run() { echo "== $* start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
        "$PY" -m studies.generalisation "$@"; echo "== rc=$? end $(date -u +%FT%T)"; }
if [ "$1" = A ]; then
  run --sim pedestrian --episodes 300 --gate-episodes 300 --cache $out/regen22-pedestrian.json
  run --sim sumo --episodes 300 --gate-episodes 300 --cache $out/regen22-sumo.json
else
  run --sim highway --episodes 300 --gate-episodes 300 --cache $out/regen22-highway.json
  run --sim ugv --episodes 300 --gate-episodes 300 --by-movers --cache $out/regen22-ugv.json
  run --sim ugv --episodes 100 --gate-episodes 200 --grounds unseen --unseen ugv-fields:test:2+ \
      --out $out/scratch-crowded.md --cache $out/regen22-ugv-2plus.json
  run --sim ugv --extras-only
fi

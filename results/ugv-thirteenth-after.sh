#!/bin/bash
# Issue 63 ("each small-budget study <= 30 min wall on this machine"), thirteenth session (2026-11-29), second run:
# the small UGV study after the two costs cut this session (the denoiser's mish from one exponential, 9b6fc1c; the
# calibration's mover velocities compiled, c4d58dd), on an idle machine as the first run (results/ugv-thirteenth.sh:
# 36.4 min wall, 69.3 trial-min). Estimated before the run from a paired Diffusion-QL trial (205 -> 185 s) and the
# profile: some 66 trial-min, some 34 min wall.
# Rule, written before the run: nothing else runs on the machine meanwhile; the study's own "wall time" line <= 30 min
# -> the target is met on this machine at this commit, measured; more -> not met, the trial-minutes per method beside
# the first run's. Not finished by 23:35 UTC -> reported as not measured (resumable: finished trials are kept).
# The table replaces section `ugv` (the present code's rows): the Diffusion rows move by float rounding over 4,000
# updates and SAGE's by the compiled velocities' last bits in its τ bounds; the others must equal the first run's.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== ugv start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study ugv --budget small --cpus 2 --max-concurrent 2 \
  --out results/ugv-small-thirteenth-after --section ugv --results-doc docs/results.md
echo "== rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"

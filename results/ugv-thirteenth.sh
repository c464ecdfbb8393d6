#!/bin/bash
# Issue 63 ("each small-budget study <= 30 min wall on this machine"), thirteenth session (2026-11-29): the small UGV
# study at the present code on an idle machine. The twelfth session's run (results/ugv-small-twelfth, 43.7 min wall,
# 83.4 trial-min) shared both cores with this session's tests and two cycles studies: every method's trial-minutes
# were 1.7-2x those of the idle run at 19343f3 (results/ugv-small-2cores: 20.4 min wall, 38.1 trial-min), including
# methods whose code had not changed (Diffusion-QL 10.7 -> 18.9, TEB 5.0 -> 8.7), so it did not measure the code.
# Rule, written before the run: nothing else runs on the machine meanwhile (the lead only reads and writes);
# the study's own "wall time" line <= 30 min -> the target is met on this machine at this commit, measured;
# more -> not met, and the trial-minutes per method say where. Not finished by 22:35 UTC -> reported as not measured
# (resumable: finished trials are kept in trials/). The learners' rows must equal the twelfth run's (no training code
# changed since 2412800 but the live worker's promotion, which the study does not use); TEB's may move a few points.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== ugv start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study ugv --budget small --cpus 2 --max-concurrent 2 \
  --out results/ugv-small-thirteenth --section ugv --results-doc docs/results.md
echo "== rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"

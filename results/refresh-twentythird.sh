#!/bin/bash
# Issue 63, twenty-third session (2026-11-30): the two arm tables still "device not recorded" (route-shift-sac-expert,
# made at 7416937; highway-40k, made at ec5a324) made again at this commit on this session's Intel Xeon host, nothing
# else heavy running, each into its own folder and its section. Reading, written before the run: as
# refresh-twentysecond.sh's (the table replaces its section with the processor and wall time in its header; the reading
# in docs/results.md is rewritten to its rows; a direction that changed is said so, with the earlier rows named).
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== route-shift-sac-expert start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study route-shift --budget small --cpus 2 --max-concurrent 2 --set study.expert=sac \
  --out results/route-shift-sac-expert-twentythird --section route-shift-sac-expert --results-doc docs/results.md
echo "== route-shift-sac-expert rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"
echo "== highway-40k start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study highway --budget small --train-steps 40000 --cpus 2 --max-concurrent 2 \
  --methods sac,sage --out results/highway-40k-twentythird --section highway-40k --results-doc docs/results.md
echo "== highway-40k rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"

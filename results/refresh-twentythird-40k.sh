#!/bin/bash
# Issue 63, twenty-third session: the highway-40k arm (the second table of refresh-twentythird.sh, stopped there before
# its first trial) started in the session's last hour and stopped before the session ends; a later invocation of the
# same command resumes its finished trials (the table's wall time sums every invocation, stopped ones included).
# Reading as refresh-twentythird.sh's, written before the run.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== highway-40k start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study highway --budget small --train-steps 40000 --cpus 2 --max-concurrent 2 \
  --methods sac,sage --out results/highway-40k-twentythird --section highway-40k --results-doc docs/results.md
echo "== highway-40k rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"

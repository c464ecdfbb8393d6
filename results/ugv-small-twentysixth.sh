#!/bin/bash
# Amendment to results/ugv-30k.sh, written 04:47 UTC while its study ran and before any of its rows was read: learner
# rows reproduce only on the processor kind that made them (studies/host_speed.py), and the committed small table
# (results/ugv-small-fifteenth) is an Intel host's. So the small budget is run again on this session's host after the
# 30,000-step study, and the reading's "at 6,000" column is read from this run (the Intel table beside it, as a
# check of how much the host moves the rows). The rest of the reading stands as written.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== ugv-small-twentysixth start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study ugv --budget small --cpus 2 --max-concurrent 2 \
  --out results/ugv-small-twentysixth --section ugv-small-twentysixth --results-doc docs/results.md
echo "== ugv-small-twentysixth rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python results/ugv_budget_read.py results/ugv-small-twentysixth results/ugv-30k > results/ugv-30k-read.md
.venv/bin/python results/ugv_budget_read.py results/ugv-small-fifteenth results/ugv-small-twentysixth \
  > results/ugv-small-hosts-read.md

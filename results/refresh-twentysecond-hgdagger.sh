#!/bin/bash
# Issue 63, twenty-second session (2026-11-30): the pedestrian-hgdagger arm's table (made at 3e2267b, "device not
# recorded") made again at this commit on this session's Intel Xeon host, nothing else running, into its own folder
# and section. Reading, written before the run: as refresh-twentysecond.sh's (the table replaces its section, the
# reading in docs/results.md is rewritten to its rows, a changed direction is said so).
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== pedestrian-hgdagger start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study pedestrian --budget small --cpus 2 --max-concurrent 2 --set study.expert=hg-dagger \
  --out results/pedestrian-hgdagger-twentysecond --section pedestrian-hgdagger --results-doc docs/results.md
echo "== pedestrian-hgdagger rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"

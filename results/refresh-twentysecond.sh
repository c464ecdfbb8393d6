#!/bin/bash
# Issue 63 ("every study table states its wall time and the device"), twenty-second session (2026-11-30): the
# pedestrian, route-shift and highway tables of docs/results.md were made at cd5d8bc, before the study header named
# the processor ("device not recorded"). Made again here at this commit, one after another, nothing else running,
# on this session's host (Intel Xeon, 2 cores), each into its own folder and its own section.
# Reading, written before the run: each table replaces its section as it comes (the code has moved since cd5d8bc and
# the processor differs, so every learner's row is a redraw, not a check of the old one); docs/results.md's reading of
# each study is rewritten to the new rows, and a reading whose direction changes (two methods apart that now overlap,
# or the reverse) is said so. Each study's own wall time is read against issue 63's 30-minute target on this host.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
for study in pedestrian route-shift highway; do
  echo "== $study start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  .venv/bin/python -m app.cli study "$study" --budget small --cpus 2 --max-concurrent 2 \
    --out "results/$study-small-twentysecond" --section "$study" --results-doc docs/results.md
  echo "== $study rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"
done

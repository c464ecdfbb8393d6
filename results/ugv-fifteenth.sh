#!/bin/bash
# Issue 63 ("each small-budget study <= 30 min wall on this machine"), fifteenth session (2026-11-30): the small UGV
# study on a third host, an Intel Xeon (2 cores; `python -m studies.host_speed --repeat 3` idle at the session's start:
# 1,670-1,707 UGV steps/s and 180-183 SAC updates/s, about 2.0x the AMD EPYC host of the thirteenth and fourteenth
# sessions, 811-833 and 86-102), code unchanged since the fourteenth session's last study code.
# Rule, written before the run: nothing else runs on the machine meanwhile; the study's own "wall time" line <= 30 min
# -> the target is met on this host at this commit, measured (the slower host's 37.7 min stays beside it, not met
# there); more -> not met, the trial-minutes per method beside the thirteenth session's. Not finished by 04:10 UTC ->
# reported as not measured (resumable: finished trials are kept).
# The table replaces section `ugv`: every learner's row must equal the thirteenth session's second run (one thread,
# deterministic; the Diffusion rows may move by float rounding on another processor, TEB's by its solver); a row
# that moves otherwise is reported, with the host as the only change.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== ugv start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study ugv --budget small --cpus 2 --max-concurrent 2 \
  --out results/ugv-small-fifteenth --section ugv --results-doc docs/results.md
echo "== rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"

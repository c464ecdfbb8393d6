#!/bin/sh
# The UGV baseline of docs/generalisation.md (issue 60) at 300 episodes a ground, the gate row too; the cache keeps
# the 60-episode run's chunks (same seeds). Unseen first, then seen, then the table with the unseen ground by movers.
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
$PY -m studies.generalisation --sim ugv --episodes 300 --gate-episodes 300 --grounds unseen
$PY -m studies.generalisation --sim ugv --episodes 300 --gate-episodes 300 --grounds seen
$PY -m studies.generalisation --sim ugv --episodes 300 --gate-episodes 300 --by-movers

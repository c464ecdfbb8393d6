#!/bin/sh
# The UGV baseline of docs/generalisation.md (issue 60): the unseen ground first, then both (the cache keeps the first).
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
$PY -m studies.generalisation --sim ugv --episodes 60 --gate-episodes 30 --grounds unseen
$PY -m studies.generalisation --sim ugv --episodes 60 --gate-episodes 30

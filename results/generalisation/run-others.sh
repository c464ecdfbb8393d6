#!/bin/sh
# The other simulators' generalisation tables (issue 60) at 60 episodes a ground (30 for the gate row), written to a
# scratch file while the UGV run writes docs/generalisation.md; then written there from the cache with --cached-only.
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
for sim in pedestrian sumo highway; do
  $PY -m studies.generalisation --sim $sim --episodes 60 --gate-episodes 30 --out results/generalisation/scratch.md
done

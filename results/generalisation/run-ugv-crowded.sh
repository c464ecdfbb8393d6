#!/bin/sh
# The unseen UGV ground restricted to test fields with two or more movers (issue 60's target names them): 100 episodes, 200 for the gate row (the first run had 100).
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
/work/main/.venv/bin/python -m studies.generalisation --sim ugv --episodes 100 --gate-episodes 200 --grounds unseen \
  --unseen ugv-fields:test:2+ --out results/generalisation/scratch-crowded.md
/work/main/.venv/bin/python -m studies.generalisation --sim ugv --extras-only  # its subsection of docs/generalisation.md

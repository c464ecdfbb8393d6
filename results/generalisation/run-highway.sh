#!/bin/sh
# highway-shift after its test split was filtered by the expert (issue 60): the expert alone, then the table.
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
$PY -m app.cli expert --sim highway --scenario highway-shift:test --episodes 60 --seed 3000000 2>/dev/null
$PY -m studies.generalisation --sim highway --episodes 60 --gate-episodes 30 --out results/generalisation/scratch.md

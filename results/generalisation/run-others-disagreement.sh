#!/bin/sh
# Issue 60, the curiosity candidate on the other simulators (docs/notes/novelty_probe.md): the disagreement's reference
# and τ bounds measured on each default policy's training scenarios (50 drives each), then its generalisation table at
# the committed size of the other simulators' tables (60 episodes a ground, 30 for the gate row).
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=${PY:-.venv/bin/python}
SETS="--set gate.curiosity_signal=disagreement --set gate.curiosity_reference=fitted"
stamp() { echo "== $(date -u +%FT%TZ) $*"; }
for pair in pedestrian:crossing,rare highway:train sumo:c1,c2; do
  sim=${pair%%:*}; seen=${pair#*:}
  run=runs/$sim-disagreement
  stamp "$sim: refit-bounds on $seen"
  [ -e $run/checkpoint.pt ] || $PY -m app.cli gate refit-bounds policies/$sim-default --scenario $seen $SETS \
      --episodes 50 --out $run
  stamp "$sim: generalisation table"
  $PY -m studies.generalisation --sim $sim --run $run --episodes 60 --gate-episodes 30 --seen $seen \
      --cache results/generalisation/$sim-disagreement.json --out results/generalisation/scratch-disagreement-others.md
done
stamp done

#!/bin/sh
# Issue 60, exploratory ablation (no refit): the committed UGV gate with curiosity switched off (τ fixed at the middle
# of its bounds, gate.use_curiosity=false) on ugv-fields:test, 100 episodes, against the baseline's first 100 (same
# seeds, from the cache). Fear's parts need no run: the table's "fear AUROC (its parts ĉ, σ̂)" column ranks them; a
# gate on ĉ or σ̂ alone (gate.beta=1 / 0) changes fear itself and needs its τ bounds measured again (not done here).
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=/work/main/.venv/bin/python
OUT=results/generalisation/scratch-ablation.md
$PY -m studies.generalisation --sim ugv --episodes 100 --gate-episodes 100 --grounds unseen \
    --set gate.use_curiosity=false --out $OUT
$PY -m studies.generalisation --sim ugv --episodes 100 --gate-episodes 100 --grounds unseen --cached-only --out $OUT.baseline
$PY -m experiments.generalisation_rule --candidate policies/ugv-default --candidate-cache results/generalisation/ugv.json --candidate-set gate.use_curiosity=false --episodes 100

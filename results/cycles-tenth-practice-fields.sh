#!/bin/bash
# Issue 62, tenth session (2026-11-29): arm PF, practice alone on the unseen two-mover field
# (finetune.practice_episodes=3 on ugv-fields:test:1, unseen test:4). Why (docs/notes/forgetting_anatomy.md, arm W):
# on this field the takeover rises over the cycles because the versions' own plans leave what the world model learned
# (σ̂ 1.4-2.4x the base's); practice puts the versions' own drives of the field, collisions included, into the buffer
# the model is refitted on, and on UGV 4 it gave the lowest takeover measured (Q4: 0.026). sage only, five seeds,
# paired by seed against results/cycles-small-fields-defaults (takeover first 0.303, last 0.539; alone 0.60; static
# 0.59). Resumable (rerun this script).
# Rule, written before the run (committed with this script):
#   primary: takeover_last mean <= 0.303 (not above the first cycle's) and below the control's, with at most one seed
#     of five above its control seed; guards: alone_success_last mean >= 0.60, static_success_last mean >= 0.54.
#   All hold: reported as the remedy for the unseen field's rising takeover; practice_episodes stays an option (its
#   UGV 3 arm, Q3, failed its own primary; no default changes on one ground). Primary fails: not a remedy there.
#   Not finished by 16:20 UTC: not measured, with the trials that finished.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== PF start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc docs/results.md --set finetune.practice_episodes=3 --out results/cycles-small-fields-practice \
  --set study.scenario=ugv-fields:test:1 --set study.unseen_scenario=ugv-fields:test:4 --section cycles-fields-practice
echo "== rc=$? end $(date -u +%FT%T)"

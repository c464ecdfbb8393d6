#!/bin/bash
# Issue 62, tenth session (2026-11-29): arm W, the world model held within a run of cycles
# (finetune.refit_world_model=false: every version's gate keeps the base's world model and τ bounds, the ones the
# generalisation table measured on unseen fields). Why: on the unseen two-mover field (cycles-fields-defaults)
# takeover rises from 30% to 54% over nine cycles, and already jumps to 66-76% in cycle 2 on three seeds of five,
# while on UGV 3 it falls; the rounds refit the world model on a few hundred session steps, and on ground that model
# never saw the refit may change fear more than the policy changes. sage only, five seeds, the present defaults
# otherwise. Resumable (rerun this script).
#   W-fields: ugv-fields:test:1 (unseen test:4), paired by seed against results/cycles-small-fields-defaults.
#   W3 (confirmation, run only if W-fields holds): UGV 3, paired against results/cycles-small-defaults.
# Rule, written before the run (committed with this script):
#   W-fields primary: takeover_last mean <= 0.303 (not above the first cycle's) and below the control's (0.539),
#     with at most one seed of five above its control seed; guards: alone_success_last mean >= 0.60 (control),
#     static_success_last mean >= 0.54 (control 0.59 - 0.05).
#   W3 guards: alone_success_last mean >= 0.77, takeover_last mean <= 0.10, static_success_last mean >= 0.81,
#     collision_cycles_above_first summed <= 5 (the control's 0.82, 0.089, 0.86, 4, with the S arm's margins).
#   W-fields and W3 hold: refit_world_model=false becomes the fine-tuning default. W-fields holds, W3 does not:
#   reported, not adopted. W-fields fails: not a remedy for the rising takeover. Not finished by 16:00 UTC: not
#   measured, with the trials that finished.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?fields or 3}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  shift
  nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set finetune.refit_world_model=false "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  fields) run W-fields --out results/cycles-small-fields-fixed-model --set study.scenario=ugv-fields:test:1 \
    --set study.unseen_scenario=ugv-fields:test:4 --section cycles-fields-fixed-model ;;
  3) run W3 --out results/cycles-small-fixed-model --section cycles-fixed-model ;;
esac

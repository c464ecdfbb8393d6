#!/bin/bash
# Issue 62, eleventh session (2026-11-29): arm L, the dual's step size ten times the default in the fine-tuning rounds
# (--set learner.lambda_lr=0.1; the default 0.01). Why: in the present defaults' rounds λ only rises 1 -> 3.5-4.4 over
# eight rounds (λF ~0.3 against Q ~40, docs/notes/forgetting_anatomy.md), so fear regularisation barely shapes what a
# round learns; on the unseen two-mover field takeover rises 30% -> 54% because fear (ĉ, and σ̂ 1.4-2.4x the base's)
# is high along the versions' own plans. A λ that acts in the critic target (-λF per step, reward ~1 per step) should
# steer the versions toward plans whose fear is low, which is what the gate reads. fear_scale=q (λ on the actor's
# immediate term) was measured before and brought no gain; this arm moves λ itself. sage only, five seeds, the present
# defaults otherwise. Resumable (rerun this script with the same argument).
#   L-fields: ugv-fields:test:1 (unseen test:4), paired by seed against results/cycles-small-fields-defaults
#     (alone 0.60, takeover last 0.539, static 0.59, collision cycles 2).
#   L3: UGV 3, paired against results/cycles-small-defaults (alone 0.82, takeover last 0.089, static 0.86,
#     collision cycles 4). Both arms run at once.
# Rule, written before the run (committed with this script):
#   Mechanism M: λ at the end of the last round (rounds' lam_end) >= 10 on at least four of five seeds of each arm;
#     if M fails, the lever was not applied and the arm is undecided whatever its outcome.
#   L-fields primary: takeover_last mean <= 0.303 (not above the first cycle's) and below the control's 0.539, with at
#     most one seed of five above its control seed; guards: alone_success_last mean >= 0.60, static_success_last mean
#     >= 0.54.
#   L3 guards: alone_success_last mean >= 0.77, takeover_last mean <= 0.10, static_success_last mean >= 0.81,
#     collision_cycles_above_first summed <= 5. L3 primary (issue 62's target): alone_success_last mean >= 0.90.
#   L-fields primary + guards and L3 guards hold: lambda_lr 0.1 becomes the fine-tuning rounds' default. L-fields holds,
#   L3's guards do not: reported, not adopted. L-fields fails: a larger dual step is not a remedy for the rising
#   takeover. Not finished by 18:45 UTC: not measured, with the trials that finished.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?fields or 3}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  shift
  nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set learner.lambda_lr=0.1 "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  fields) run L-fields --out results/cycles-small-fields-lambda --set study.scenario=ugv-fields:test:1 \
    --set study.unseen_scenario=ugv-fields:test:4 --section cycles-fields-lambda ;;
  3) run L3 --out results/cycles-small-lambda --section cycles-lambda ;;
esac

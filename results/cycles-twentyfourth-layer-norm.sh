#!/bin/bash
# Issue 62, twenty-fourth session (2026-11-30): arm N, RLPD's layer-normed critics in the rounds
# (--set learner.critic_layer_norm=true; default false). Why (issue 62 item 2 names it; never measured here): the
# rounds' critics rate the agent's own action above the expert's in 77-81% of takeover states (issue 62's
# measurements), the extrapolation to actions off the data that RLPD's layer norm is there to bound; of the anchors
# the issue lists, equal shares, the critic warm-up and a higher update-to-data ratio were measured (forgetting_anatomy),
# layer norm was not. The base's critics have no norms: the round fits the new critics to the saved ones first
# (1,000 updates on the buffer's states at recorded and policy actions, `ActorLearner.distil_critic`), so they start
# as the base's values, not a random function. Nothing is tuned: RLPD's placement (after each hidden linear, before
# the ReLU), no other setting changed. sage only, five seeds, the present defaults otherwise. The control is run here
# again at this code beside the arm (`control`), paired by seed.
# Rule, written before the run (committed with this script, before any of its output exists):
#   N3 primary: alone_success_last mean >= 0.90 (issue 62's target) with at most one seed lower than its control seed.
#     Guards: takeover_last mean <= 0.10, static_success_last mean >= control's - 0.05, unseen_success_last mean >=
#     control's - 0.10, collision_cycles_above_first summed <= control's.
#   Primary and guards hold: the confirmation on UGV 4 (`control4`, `norm4`) decides adoption as the rounds' default
#     (alone >= 0.90 with at most one seed lower than its control, takeover_last <= 0.10, static >= control's - 0.05).
#   Primary holds, a guard fails: the trade, reported, not adopted. Primary fails: not the lever; reported, and UGV 4
#     is not run.
#   Read beside the verdict, not deciding it: the rounds' mean ω (omega_mean) and the critics' distillation error.
#   Not finished by 02:00 UTC (2026-12-01): the seeds that finished in both arms are reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?control, norm, control4 or norm4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  control) run control --out results/cycles-small-defaults-24 --section cycles-defaults-24 ;;
  norm) run N3 --out results/cycles-small-layer-norm --section cycles-layer-norm --set learner.critic_layer_norm=true ;;
  control4) run control4 --out results/cycles-small-ugv4-defaults-24 --section cycles-ugv4-defaults-24 \
    --set study.scenario=4 ;;
  norm4) run N4 --out results/cycles-small-ugv4-layer-norm --section cycles-ugv4-layer-norm --set study.scenario=4 \
    --set learner.critic_layer_norm=true ;;
esac

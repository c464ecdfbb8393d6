#!/bin/bash
# Issue 62, twenty-fourth session (2026-12-01): arm Z, RLPD's / REDQ's critic ensemble in the rounds
# (--set learner.critics=10 --set learner.critic_target_subset=2: ten critics, the TD target the minimum of two drawn
# at random every update, the actor's value and ω the ten's mean; RLPD's published setting, not tuned). Why: issue 62
# item 2 names critic ensembles beside layer norm; arm N (layer norm, this session) did not make the critics humbler
# about the agent's actions at takeover states (ω rose). The base has two critics: the round fits the ten new ones to
# them first (member z to saved member z mod 2, `ActorLearner.distil_critic`; the critics' Adam starts fresh, its
# saved moments being of two members' shapes). sage only, five seeds, the present defaults otherwise.
# Control: arm N's control at 8688b46 (`cycles-defaults-24`); the defaults' code path is unchanged since (two critics,
# no subset: the same operations), which `control-check` (the control again at this code, not written into the docs)
# checks seed for seed beside the arm.
# Rule, written before the run (committed with this script, before any of its output exists), arm N's:
#   Z3 primary: alone_success_last mean >= 0.90 (issue 62's target) with at most one seed lower than its control seed.
#     Guards: takeover_last mean <= 0.10, static_success_last mean >= control's - 0.05, unseen_success_last mean >=
#     control's - 0.10, collision_cycles_above_first summed <= control's.
#   Primary and guards hold: the confirmation on UGV 4 (`control4`, `ensemble4`) decides adoption as the rounds'
#     default (alone >= 0.90 with at most one seed lower than its control, takeover_last <= 0.10, static >= control's
#     - 0.05). Primary holds, a guard fails: the trade, reported, not adopted. Primary fails: not the lever; reported,
#     UGV 4 not run.
#   Read beside the verdict, not deciding it: the rounds' mean ω and the critics' distillation error.
#   Not finished by 02:10 UTC: the seeds that finished in both arms are reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?ensemble, control-check, control4 or ensemble4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
ensemble=(--set learner.critics=10 --set learner.critic_target_subset=2)
case $arm in
  ensemble) run Z3 --results-doc docs/results.md --out results/cycles-small-ensemble --section cycles-ensemble \
    "${ensemble[@]}" ;;
  control-check) run control-check --out runs/cycles-control-check-24 ;;
  control4) run control4 --results-doc docs/results.md --out results/cycles-small-ugv4-defaults-24 \
    --section cycles-ugv4-defaults-24 --set study.scenario=4 ;;
  ensemble4) run Z4 --results-doc docs/results.md --out results/cycles-small-ugv4-ensemble \
    --section cycles-ugv4-ensemble --set study.scenario=4 "${ensemble[@]}" ;;
esac

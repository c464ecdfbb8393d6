#!/bin/bash
# Issue 62, twenty-seventh session (2026-12-01, written 07:22 UTC before any run of it): arm I, IBRL in the rounds
# (--set learner.ibrl=true; default false). Why: IBRL is the one anchor issue 62 item 2 names that was never measured
# here (equal shares, the critic warm-up, a higher update-to-data ratio, layer norm, a critic ensemble and Cal-QL were:
# docs/notes/forgetting_anatomy.md, none kept). The rounds lose alone what they learn under supervision (UGV 3 alone
# 0.72 on this host kind), and a clone of the privileged expert drives the crossing alone (the observability probe);
# IBRL keeps such a clone beside the RL actor and lets the critics pick, state by state, whichever proposal they value
# higher, when acting and in the TD target. Nothing is tuned: IBRL's published structure (π_IL cloned on the expert's
# rows only, greedy actor proposal at evaluation, bootstrap proposal in the target), π_IL cloned 1,000 updates a round
# (the field's default, chosen before any run) and kept at its lowest held-out takeover error; no other setting
# changed. sage only, five seeds, the present defaults otherwise. The control is run here again at this code on this
# host (an AMD EPYC like the twenty-sixth session's; learner rows reproduce only on the processor kind that made them),
# beside the arm, paired by seed.
# Rule (arm Q's, written before the run, committed with this script before any of its output exists):
#   I3 primary: alone_success_last mean >= 0.90 (issue 62's target) with at most one seed lower than its control seed.
#     Guards: takeover_last mean <= 0.10, static_success_last mean >= control's - 0.05, unseen_success_last mean >=
#     control's - 0.10, collision_cycles_above_first summed <= control's.
#   Primary and guards hold: the confirmation on UGV 4 (`control4`, `ibrl4`) decides adoption as the rounds' default
#     (alone >= 0.90 with at most one seed lower than its control, takeover_last <= 0.10, static >= control's - 0.05).
#   Primary holds, a guard fails: the trade, reported, not adopted. Primary fails: not the lever; reported, and UGV 4
#     is not run.
#   Read beside the verdict, not deciding it: the alone success's change over the control, the rounds' mean ω and
#     π_IL's held-out error against the RL actor's.
#   Not finished by 08:30 UTC: the seeds that finished in both arms are reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?control, ibrl, control4 or ibrl4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  control) run control --out results/cycles-small-defaults-27 --section cycles-defaults-27 ;;
  ibrl) run I3 --out results/cycles-small-ibrl --section cycles-ibrl --set learner.ibrl=true ;;
  control4) run control4 --out results/cycles-small-ugv4-defaults-27 --section cycles-ugv4-defaults-27 \
    --set study.scenario=4 ;;
  ibrl4) run I4 --out results/cycles-small-ugv4-ibrl --section cycles-ugv4-ibrl --set study.scenario=4 \
    --set learner.ibrl=true ;;
esac

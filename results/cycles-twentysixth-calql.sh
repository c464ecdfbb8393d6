#!/bin/bash
# Issue 62, twenty-sixth session (2026-12-01): arm Q, Cal-QL's conservative critic term in the rounds
# (--set learner.conservative_weight=5; default 0). Why (issue 62 item 2 names Cal-QL; never measured here): the
# rounds' critics rate the agent's own action above the expert's in 77-81% of takeover states (issue 62's
# measurements), values of actions off the data that a conservative term pushes under the recorded actions' (the
# expert's at takeovers, the base's on the anchor's drives, the agent's own elsewhere), and Cal-QL's floor (the
# recorded return to go) keeps that push from unlearning what the data achieved. Of the anchors the issue lists,
# equal shares, the critic warm-up, a higher update-to-data ratio, layer norm and a critic ensemble were measured
# (docs/notes/forgetting_anatomy.md), Cal-QL and IBRL were not. Nothing is tuned: α = 5 and 10 actions of each kind
# per state are CQL's and Cal-QL's published settings; no other setting changed. sage only, five seeds, the present
# defaults otherwise. The control is run here again at this code and on this host (learner rows reproduce only on the
# processor kind that made them) beside the arm, paired by seed.
# Rule, written before the run (committed with this script, before any of its output exists), as arm N's:
#   Q3 primary: alone_success_last mean >= 0.90 (issue 62's target) with at most one seed lower than its control seed.
#     Guards: takeover_last mean <= 0.10, static_success_last mean >= control's - 0.05, unseen_success_last mean >=
#     control's - 0.10, collision_cycles_above_first summed <= control's.
#   Primary and guards hold: the confirmation on UGV 4 (`control4`, `calql4`) decides adoption as the rounds' default
#     (alone >= 0.90 with at most one seed lower than its control, takeover_last <= 0.10, static >= control's - 0.05).
#   Primary holds, a guard fails: the trade, reported, not adopted. Primary fails: not the lever; reported, and UGV 4
#     is not run.
#   Read beside the verdict, not deciding it: the rounds' mean ω (omega_mean) and conservative loss.
#   Not finished by 07:00 UTC: the seeds that finished in both arms are reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?control, calql, control4 or calql4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  control) run control --out results/cycles-small-defaults-26 --section cycles-defaults-26 ;;
  calql) run Q3 --out results/cycles-small-calql --section cycles-calql --set learner.conservative_weight=5 ;;
  control4) run control4 --out results/cycles-small-ugv4-defaults-26 --section cycles-ugv4-defaults-26 \
    --set study.scenario=4 ;;
  calql4) run Q4 --out results/cycles-small-ugv4-calql --section cycles-ugv4-calql --set study.scenario=4 \
    --set learner.conservative_weight=5 ;;
esac

#!/bin/bash
# Issue 62, eighteenth session (2026-11-30): arm C, coaching (`--set study.coach_share=0.25`: on a quarter of the
# steps the agent drives, the scripted expert's action at that state is recorded as a label, imitated by the rounds
# like a takeover's, never executed; core.experts.CoachingExpert, the headless stand-in for the dashboard's new coach
# input). Why (seventeenth session, docs/notes/forgetting_anatomy.md): what holds the versions near 0.8 alone on UGV 3
# is how many of the expert's labels fall on the states the agent reaches itself; the diagnosis that labelled a
# quarter of the agent's steps (monkeypatched, its takeover column counting the labels) reached 0.92 alone. This is
# the same lever as a product feature, with the takeover column counting the expert's driving only. 0.25 is the
# diagnosis' share, chosen before that run, not tuned. sage only, five seeds, the present defaults otherwise; paired
# by seed against the Intel controls of the seventeenth session (this host is an Intel Xeon too; the Intel hosts
# reproduced each other's rows seed for seed), coach_share 0 being the defaults bit for bit (tested).
#   UGV 3 control cycles-defaults-intel-17: alone 0.84, unseen 0.86, takeover last 0.086, static 0.78, coll. cycles 3.
#   field control cycles-fields-defaults-intel (ugv-fields:test:1, unseen test:4): alone 0.00, takeover last 0.595,
#     static 0.64, collision cycles 2.
#   UGV 4 control cycles-ugv4-defaults-intel-17: alone 1.00, unseen 0.64, takeover last 0.008, static 0.73, coll. 5.
# Rule, written before the run (committed with this script):
#   C3 primary: alone_success_last mean >= 0.90 with at most one seed lower than its control seed. Guards:
#     takeover_last mean <= 0.10, static_success_last mean >= control's - 0.05, unseen_success_last mean >= control's
#     - 0.10, collision_cycles_above_first summed <= control's.
#   All hold: the docs say coaching is how the rounds reach the alone target on UGV 3 (the dashboard's coach input the
#     recommended way to give the rounds labels), and Cfield / C4 are read as its transfer (reported, not a gate on
#     it). Primary holds, a guard fails: the trade, reported. Primary fails: reported; coaching stays an input.
#   Whatever the outcome the headless default stays coach_share 0 (the paper's protocol: the studies' rows stay
#   comparable); the dashboard's coach input is there either way (a person chooses to use it).
#   Cfield primary: alone_success_last mean >= 0.60 (the control 0.00) with takeover_last mean below the control's.
#   Not finished by 11:30 UTC: the seeds that finished are reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?coach3, coachfield or coach4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 2 --max-concurrent 2 --methods sage \
    --results-doc docs/results.md --set study.coach_share=0.25 "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  coach3) run C3 --out results/cycles-small-coach --section cycles-coach ;;
  coachfield) run Cfield --out results/cycles-small-fields-coach --section cycles-fields-coach \
    --set study.scenario=ugv-fields:test:1 --set study.unseen_scenario=ugv-fields:test:4 ;;
  coach4) run C4 --out results/cycles-small-ugv4-coach --section cycles-ugv4-coach --set study.scenario=4 ;;
esac

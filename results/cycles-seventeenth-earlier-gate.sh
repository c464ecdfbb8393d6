#!/bin/bash
# Issue 62, seventeenth session (2026-11-30): arm T, the versions' gate asks earlier (--set learner.gate.tau_scale=0.8:
# every fine-tuned version deploys its gate at τ scale 0.8 instead of the UGV default's 1.1, about 27% lower τ; the
# first cycle, v0000, keeps the default's gate, so it pairs with the control's). Why (measured this session,
# docs/notes/forgetting_anatomy.md): the present rounds reach the alone target when the expert's labels cover the
# states the versions reach (0.92 against 0.84), and carrying the expert's onset action back over the approach (arm B)
# does not stand in for them. Within the takeover protocol the only way to get the expert's own choices on more of the
# approach is to hand over earlier: a lower τ fires on states further from the danger, so more of each approach is
# driven, and labelled, by the expert. The cost is takeover: the issue asks for <= 10% in the last cycle, with the
# versions' own gate. 0.8 is chosen before the run (a scale the UGV operating-point grids held, 0.7-1.1
# on train ground), not tuned. sage only, five seeds, the present defaults otherwise, paired by seed against this host's
# control earlier this session (cycles-defaults-intel-17: alone 0.84, unseen 0.86, takeover last 0.086, static 0.78,
# collision cycles 3).
# Rule, written before the run (committed with this script):
#   T3 primary: alone_success_last mean >= 0.90 (issue 62's target) with at most one seed lower than its control seed.
#     Guards: takeover_last mean <= 0.10, static_success_last mean >= control's - 0.05, unseen_success_last mean >=
#     control's - 0.10, collision_cycles_above_first summed <= control's.
#   Primary and guards hold: the pre-registered confirmation on UGV 4 (`earlier4` against this session's UGV 4 control,
#     cycles-ugv4-defaults-intel-17) decides adoption (alone >= 0.90 with at most one seed lower than its control,
#     takeover_last <= 0.10, static >= control's - 0.05).
#   Primary holds, a guard fails: the trade, reported, not adopted. Primary fails: not the lever; reported.
#   Not finished by 09:00 UTC: the seeds that finished are reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?earlier or earlier4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  earlier) run T3 --out results/cycles-small-earlier-gate --section cycles-earlier-gate --set learner.gate.tau_scale=0.8 ;;
  earlier4) run T4 --out results/cycles-small-ugv4-earlier-gate --section cycles-ugv4-earlier-gate --set study.scenario=4 \
    --set learner.gate.tau_scale=0.8 ;;
esac

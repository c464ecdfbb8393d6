#!/bin/bash
# Issue 62, seventeenth session (2026-11-30): arm B, look-back labels (--set learner.lookback_labels=10; default 0, the
# paper's SAGE). Why (measured this session, docs/notes/forgetting_anatomy.md): the present rounds reach issue 62's
# alone target on UGV 3 when the expert's labels cover the states the versions reach (the diagnosis with a label on
# every agent step: alone 0.92, static 0.87, against 0.84 and 0.78), so the plateau is where the takeover protocol puts
# its labels: only on the steps the expert drove after the gate fired, none on the agent's approach that led there.
# Within the protocol (only takeover data; a person at the dashboard gives nothing more), the agent's last steps before
# each takeover onset (same episode, the agent driving) become imitation rows labelled with the expert's first action
# at the onset (`core/sage/learner.py` `_look_back`; ω-weighted like every takeover row; what was executed is
# unchanged). 10 steps is the gate's label horizon on the UGV (a violation within 1 s, 0.1 s a step), chosen before the
# run, not tuned. sage only, five seeds, the present defaults otherwise, paired by seed against this host's control
# run earlier this session (section cycles-defaults-intel-17, at 6e70f01: alone 0.84, unseen 0.86, takeover last
# 0.086, static 0.78, collision cycles 3; the code since changes nothing where lookback_labels is 0).
# Rule, written before the run (committed with this script):
#   B3 primary: alone_success_last mean >= 0.90 (issue 62's target) with at most one seed lower than its control seed.
#     Guards: takeover_last mean <= 0.10, static_success_last mean >= control's - 0.05, unseen_success_last mean >=
#     control's - 0.10, collision_cycles_above_first summed <= control's.
#   Primary and guards hold: the pre-registered confirmation on UGV 4 (`control4`, `lookback4`, run side by side)
#     decides adoption (alone >= 0.90 with at most one seed lower than its control, takeover_last <= 0.10, static >=
#     control's - 0.05).
#   Primary holds, a guard fails: the trade, reported, not adopted. Primary fails: not the lever; reported.
#   Not finished by 09:00 UTC: the seeds that finished in both arms are reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?lookback, control4 or lookback4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  lookback) run B3 --out results/cycles-small-lookback --section cycles-lookback --set learner.lookback_labels=10 ;;
  control4) run control4 --out results/cycles-small-ugv4-defaults-intel-17 --section cycles-ugv4-defaults-intel-17 \
    --set study.scenario=4 ;;
  lookback4) run B4 --out results/cycles-small-ugv4-lookback --section cycles-ugv4-lookback --set study.scenario=4 \
    --set learner.lookback_labels=10 ;;
esac

#!/bin/bash
# Issue 62, seventeenth session (2026-11-30): arm F, the refused proposal as a failure the critic learns
# (--set learner.refused_weight=1; default 0, the paper's SAGE). Why (issue 62's measurements, read before the run):
# the gate prevents every collision, so no round's critic sees what the agent's own proposal would have done where the
# expert took over; it rates the agent's action above the expert's in 77-81% of takeover states and ω averages
# 0.69-0.75, and every alone failure of the present defaults' last versions on UGV 3 is a collision in those states.
# Issue 62 item 3 asks for "failures the critic can learn from ... without letting the robot crash". The term: on the
# steps where the expert drove *and* the step's fear was over τ (the gate judged the agent's proposal a_RL there), the
# critics' Q(s, a_RL) is held to -c*, the value a real violation's transition gets (`core/sage/sac.py`
# `refused_loss`, 128 such rows an update beside the 256 of the TD batch). Unlike arm I (thirteenth session: a reward
# cost on the executed step before the onset, which also lowered the approach every crossing needs), it labels only
# the action that was not executed. Weight 1 is chosen before the run, not tuned: each refused row weighs as a row of
# the TD batch. sage only, five seeds, the present defaults otherwise. This host is an Intel Xeon (AVX-512, as the
# fifteenth session's): the control is run here again beside the arm (`control`), which also says whether the
# fifteenth session's Intel rows (section cycles-defaults-intel: alone 0.84, unseen 0.86, takeover last 0.086,
# static 0.78, collision cycles 3) reproduce on this host; the arm is paired by seed against this run's control.
# Rule, written before the run (committed with this script):
#   F3 primary: alone_success_last mean >= 0.90 (issue 62's target) with at most one seed lower than its control seed.
#     Guards: takeover_last mean <= 0.10, static_success_last mean >= control's - 0.05, unseen_success_last mean >=
#     control's - 0.10, collision_cycles_above_first summed <= control's.
#   Primary and guards hold: the pre-registered confirmation on UGV 4 (`control4`, `refused4`) decides adoption
#     (alone >= 0.90 with at most one seed lower than its control, takeover_last <= 0.10, static >= control's - 0.05).
#   Primary holds, a guard fails: the trade, reported, not adopted. Primary fails: not the lever; reported.
#   Read beside the verdict, not deciding it: the rounds' mean ω (omega_mean) and refused_loss over cycles.
#   Not finished by 09:00 UTC: the seeds that finished in both arms are reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?control, refused, control4 or refused4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  control) run control --out results/cycles-small-defaults-intel-17 --section cycles-defaults-intel-17 ;;
  refused) run F3 --out results/cycles-small-refused --section cycles-refused --set learner.refused_weight=1 ;;
  control4) run control4 --out results/cycles-small-ugv4-defaults-intel-17 --section cycles-ugv4-defaults-intel-17 \
    --set study.scenario=4 ;;
  refused4) run F4 --out results/cycles-small-ugv4-refused --section cycles-ugv4-refused --set study.scenario=4 \
    --set learner.refused_weight=1 ;;
esac

#!/bin/bash
# Issue 62, fifteenth session (2026-11-30): a second draw of arm Q (practice alone, 3 episodes a round:
# --set finetune.practice_episodes=3; the ninth session's cycles-practice and cycles-ugv4-practice on AMD). Why: on this
# session's Intel host the defaults' cycles were a second draw of the AMD ones (docs/notes/forgetting_anatomy.md,
# fifteenth session), and five-seed means moved by up to 0.08 (static) and 0.16 (unseen) between the two draws. Q was
# the one arm that met every UGV 4 target on its draw (alone 0.98, takeover last 0.026, no cycle above the first) and
# failed UGV 3 by a difference (alone 0.76 against 0.82) inside what a redraw moves. Written at 03:52 UTC, after the
# Intel controls of UGV 3 (cycles-defaults-intel) were seen and while UGV 4's runs, before any Q run here.
#   Q3i: UGV 3, against results/cycles-small-defaults-intel.   Q4i: UGV 4, against results/cycles-small-ugv4-defaults-intel.
# Rule, written before the run (committed with this script). Each arm's two draws are pooled (ten seed-runs: the AMD
# draw against the AMD control, the Intel draw against the Intel control), per scenario:
#   practice_episodes=3 becomes the fine-tuning default (worker and studies) only if all hold:
#   (1) UGV 4: pooled alone_success_last of Q >= the pooled control's + 0.05, and Q4i >= its Intel control;
#   (2) UGV 3: pooled alone_success_last of Q >= the pooled control's - 0.03;
#   (3) both: pooled static_success_last of Q >= the pooled control's - 0.03;
#   (4) both: pooled takeover_last of Q <= the pooled control's + 0.01, collision_cycles_above_first summed over the
#       ten seed-runs <= the control's.
#   Any fails: not adopted, which clause failed reported. The issue's targets are read as well (alone >= 0.90 etc.).
#   Not finished by 05:10 UTC: the seeds that finished are reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?3 or 4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set finetune.practice_episodes=3 "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  3) run Q3i --out results/cycles-small-practice-intel --section cycles-practice-intel ;;
  4) run Q4i --out results/cycles-small-ugv4-practice-intel --set study.scenario=4 --section cycles-ugv4-practice-intel ;;
esac

#!/bin/bash
# Issue 62, fourteenth session (2026-11-30): is arm ΩA's reading on the unseen field (bc_weight=10, prior_distill=5:
# alone 1.00 on every seed against 0.60, static 0.73 against 0.59, takeover last 0.255 against 0.539 on
# ugv-fields:test:1) a property of that one field? Measured on the next test field with two or more movers,
# ugv-fields:test:4 (three movers; the unseen field of the earlier runs, where no version ever drove alone), with the
# next one after it, ugv-fields:test:6 (two movers), as its unseen field. Written at 01:32 UTC, after ΩA was seen,
# before this run. Both arms side by side, five seeds each, sage only (the frozen control's rows are v0000's, read
# from the control's first cycle). Resumable.
#   control: the present defaults on test:4.   ΩA: --set learner.bc_weight=10 --set finetune.prior_distill=5.
# Rule, written before the run (committed with this script), paired by seed:
#   The field reading is confirmed on a second field if ΩA's alone_success_last mean >= 0.80 and >= the control's,
#   its static_success_last mean >= the control's - 0.05, and its takeover_last mean <= the control's. Otherwise not
#   confirmed (reported with which clause failed). Nothing is adopted either way (UGV 3's cost stands). Not finished by
#   02:05 UTC: the seeds that finished in both arms, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?control or omega}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  shift
  nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set study.scenario=ugv-fields:test:4 --set study.unseen_scenario=ugv-fields:test:6 \
    "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  control) run control --out results/cycles-small-field4-defaults --section cycles-field4-defaults ;;
  omega) run ΩA-field4 --out results/cycles-small-field4-imitation-anchor --section cycles-field4-imitation-anchor \
    --set learner.bc_weight=10 --set finetune.prior_distill=5 ;;
esac

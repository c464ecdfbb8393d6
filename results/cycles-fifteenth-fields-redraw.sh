#!/bin/bash
# Issue 62, fifteenth session (2026-11-30): a second draw, on this session's Intel host, of the unseen field's two
# runs that read furthest apart: the defaults (cycles-fields-defaults, AMD: alone 0.60, takeover first 0.303 -> last
# 0.539, static 0.59) and arm ΩA (cycles-fields-imitation-anchor, AMD: --set learner.bc_weight=10 --set
# finetune.prior_distill=5: alone 1.00 on every seed, takeover last 0.255, static 0.73). Why: a redraw of the UGV
# defaults moved five-seed means by up to 0.16 (docs/notes/forgetting_anatomy.md, fifteenth session); whether ΩA's
# field reading is more than one draw decides whether "how hard a round imitates depends on the ground" is worth a rule.
# Written at 04:15 UTC, before either run. ugv-fields:test:1 (unseen test:4), sage only, five seeds, side by side.
# Rule, written before the run (committed with this script): ΩA's field reading replicates if in this draw ΩA's
#   alone_success_last mean >= 0.90 and >= the Intel control's + 0.20, its static_success_last mean >= the control's
#   - 0.05, and its takeover_last mean <= the control's. Otherwise it does not (which clause said). Nothing is adopted
#   either way (ΩA's UGV 3 cost stands). Not finished by 04:45 UTC: the seeds that finished, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?control or omega}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set study.scenario=ugv-fields:test:1 --set study.unseen_scenario=ugv-fields:test:4 \
    "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  control) run control-fields --out results/cycles-small-fields-defaults-intel --section cycles-fields-defaults-intel ;;
  omega) run ΩA-fields --out results/cycles-small-fields-imitation-anchor-intel \
    --section cycles-fields-imitation-anchor-intel --set learner.bc_weight=10 --set finetune.prior_distill=5 ;;
esac

#!/bin/bash
# Issue 62, ninth session (2026-11-29): the cycles study from the present defaults (disagreement curiosity, the
# fine-tuning anchor) on the two grounds not yet run with them, then one arm with the promotion's regression test.
# Resumable: each folder keeps finished trials in trials/; rerun this script to resume.
#
# 1. UGV 4 (sage + frozen), section cycles-ugv4-defaults (cycles-ugv4-anchor ran with the prediction-error curiosity).
# 2. Unseen two-mover fields: ugv-fields:test:1 as the cycle's field, ugv-fields:test:4 as its unseen one (the first
#    two test fields with two or more movers, as in cycles-fields at f8b4f54), section cycles-fields-defaults.
# 3. Arm R, UGV 3, sage only, paired by seed against results/cycles-small-defaults (section cycles-defaults):
#    --set study.regression_scenarios=1,2 (a version drives only if alone on UGV 1 and 2 it succeeds on no fewer of
#    the regression test's 10 seeds than v0000). Rule, written before the run (committed with this script):
#      primary: static_success_last mean >= 0.95 (the target: scenarios 1-2 alone no worse than the default's 1.00);
#      guards: alone_success_last mean >= 0.75, takeover_last mean <= 0.12, collision_cycles_above_first summed over
#      seeds <= cycles-defaults' sum.
#    All hold: the regression test on scenarios 1-2 becomes the UGV cycles' and worker's default promotion.
#    Primary fails: not a remedy, stays an option. Primary holds and a guard fails: reported, not adopted.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  shift
  nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 \
    --results-doc docs/results.md "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
run ugv4 --out results/cycles-small-ugv4-defaults --set study.scenario=4 --section cycles-ugv4-defaults
run fields --out results/cycles-small-fields-defaults --set study.scenario=ugv-fields:test:1 \
  --set study.unseen_scenario=ugv-fields:test:4 --section cycles-fields-defaults
run regression --out results/cycles-small-regression-defaults --methods sage --set study.regression_scenarios=1,2 \
  --section cycles-regression-defaults

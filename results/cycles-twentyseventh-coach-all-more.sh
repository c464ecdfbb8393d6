#!/bin/bash
# Issue 62, twenty-seventh session (2026-12-01, written 08:21 UTC, after arm C1 on UGV 3 and before any run of this):
# arm C1 (coaching every agent step, --set study.coach_share=1.0) on issue 62's other two grounds, to say what the
# setting that reached 0.90 alone on UGV 3 (at 14.9% takeover) does there. Nothing else changed; sage only, five
# seeds, this host (an AMD EPYC), paired by seed with controls run here:
#   UGV 4: control4 (the defaults, run now: no UGV 4 control exists on this host kind) and coach4.
#   An unseen two-mover field, ugv-fields:test:1, judged alone each cycle also on ten unseen test fields with two or
#   more movers: coachf against this session's Fctl (results/cycles-small-fields-unseen2-27, at 1897e19).
# Readings, written before the runs (committed with this script before any of its output exists), reported, no
# default changes (coaching is a person's input):
#   UGV 4: issue 62's targets read as for UGV 3: alone_success_last >= 0.90 with at most one seed lower than its
#     control seed; takeover_last <= 0.10; static_success_last >= control's - 0.05; collision cycles <= control's.
#   Field: alone on test:1 (alone_success_last) >= 0.90 with at most one seed lower than Fctl's -> "the rounds learn
#     the unseen field they are coached on"; unseen_success_last >= Fctl's + 0.10 with at most one seed lower -> "and
#     carry further to other unseen two-mover fields". Each reported as holds / fails.
#   Not finished by 09:40 UTC: the finished seeds, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?control4, coach4 or coachf}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  control4) run control4 --out results/cycles-small-ugv4-defaults-27 --section cycles-ugv4-defaults-27 \
    --set study.scenario=4 ;;
  coach4) run C1-4 --out results/cycles-small-ugv4-coach-all --section cycles-ugv4-coach-all --set study.scenario=4 \
    --set study.coach_share=1.0 ;;
  coachf) run C1-field --out results/cycles-small-fields-unseen2-coach-all --section cycles-fields-unseen2-coach-all \
    --set study.scenario=ugv-fields:test:1 --set study.unseen_scenario=ugv-fields:test:2+ --set study.coach_share=1.0 ;;
esac

#!/bin/bash
# Issue 62, twenty-eighth session (2026-12-01, written 12:27 UTC, after CW1 on UGV 3, while CW1 on UGV 4 runs, before
# any run of this): CW1 (coaching every agent step with omega = 1) on an unseen two-mover field, ugv-fields:test:1,
# judged alone each cycle also on ten unseen test fields with two or more movers (ugv-fields:test:2+), with the
# defaults driven beside it on this host kind (AMD EPYC at ~950 UGV steps/s; the faster host's control does not pair).
# Reading (the twenty-seventh session's for C1 on the field, written now; reported, no default changes):
#   alone on test:1 (alone_success_last) >= 0.90 with at most one seed lower than the control's -> "the rounds learn the
#   unseen field they are coached on"; unseen_success_last >= control's + 0.10 with at most one seed lower -> "and carry
#   further to other unseen two-mover fields"; takeover_last and static_success_last reported beside. Each holds /
#   fails. Not finished by the deadline: the finished seeds, undecided.
# Not run in the twenty-eighth session (it ended first). Launched in the twenty-ninth (2026-12-01, 18:28 UTC), the
# reading unchanged, after CW1 on UGV 4 failed its own (alone 0.76 against 0.88); the deadline now 19:03 UTC.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== cw1-field start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
field=(--set study.scenario=ugv-fields:test:1 --set study.unseen_scenario=ugv-fields:test:2+)
.venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc /tmp/ctlf-results.md --out results/cycles-small-fields-unseen2-28 --section cycles-fields-unseen2-28 \
  "${field[@]}" > results/cycles-twentyeighth-field-control.log 2>&1 &
.venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc /tmp/cwf-results.md --out results/cycles-small-fields-unseen2-coach-all-omega-one \
  --section cycles-fields-unseen2-coach-all-omega-one "${field[@]}" --set study.coach_share=1.0 \
  --set learner.advantage_clip=0 > results/cycles-twentyeighth-field-cw1.log 2>&1 &
wait
echo "== rc=$? end $(date -u +%FT%T)"

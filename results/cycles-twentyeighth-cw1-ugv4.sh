#!/bin/bash
# Issue 62, twenty-eighth session (2026-12-01, written 12:27 UTC, after arms W1 and CW1 on UGV 3 and before any run of
# this). CW1 (coaching every agent step with omega = 1: --set study.coach_share=1.0 --set learner.advantage_clip=0) drove
# UGV 3 alone at 0.96 with no seed lower than C1's, at 11.9% takeover (C1 14.7%), but its transfer to the unseen UGV 4
# fell (0.54 against 0.92). Issue 62 reads UGV 4 as its own cycles run; no UGV 4 control exists on this host kind
# (AMD EPYC at ~950 UGV steps/s), so both are driven now, side by side, five seeds, sage only:
#   ctl4: the defaults on UGV 4 (--set study.scenario=4); cw4: CW1 on UGV 4.
# Reading (written now; reported, no default changes: coaching is a person's input): cw4 against ctl4, issue 62's UGV
#   targets: alone_success_last >= 0.90 with at most one seed lower than its control seed; takeover_last <= 0.10;
#   static_success_last >= ctl4's - 0.05; collision cycles summed <= ctl4's; unseen (UGV 3) >= ctl4's - 0.10. Each
#   reported as holds / fails. Not finished by 13:15 UTC: the finished seeds, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== cw1-ugv4 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc /tmp/ctl4-results.md --out results/cycles-small-ugv4-defaults-28 --section cycles-ugv4-defaults-28 \
  --set study.scenario=4 > results/cycles-twentyeighth-ugv4-control.log 2>&1 &
.venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc /tmp/cw4-results.md --out results/cycles-small-ugv4-coach-all-omega-one \
  --section cycles-ugv4-coach-all-omega-one --set study.scenario=4 --set study.coach_share=1.0 \
  --set learner.advantage_clip=0 > results/cycles-twentyeighth-ugv4-cw1.log 2>&1 &
wait
echo "== rc=$? end $(date -u +%FT%T)"

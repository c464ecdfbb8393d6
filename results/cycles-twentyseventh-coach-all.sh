#!/bin/bash
# Issue 62, twenty-seventh session (2026-12-01, written 08:14 UTC, after arm H's diagnosis and before any run of this):
# arm C1, coaching on every step the agent drives (--set study.coach_share=1.0; default 0). Arm H read that the
# takeover data, not the learner, holds the rounds under the target on UGV 3 (HG-DAgger rounds on the same takeovers
# 0.74 against SAGE's 0.72); the seventeenth session's coverage diagnosis gave the rounds the expert's label on every
# agent step (0.92 in one draw), the eighteenth measured coaching at a quarter of the steps through the product path
# (0.82 against 0.84: not a gain). This is the full share through the product path, on this host, paired by seed with
# this session's control (results/cycles-small-defaults-27, at 3e44520; coach_share 0 leaves the rounds as they were).
# Nothing else changed; sage only, five seeds, UGV 3.
# Rule (arm Q's and arm I's, written before the run, committed with this script before any of its output exists):
#   C1 primary: alone_success_last mean >= 0.90 with at most one seed lower than its control seed. Guards:
#     takeover_last mean <= 0.10, static_success_last mean >= control's - 0.05, unseen_success_last mean >= control's
#     - 0.10, collision_cycles_above_first summed <= control's.
#   Primary and guards hold: docs/dashboard.md says that coaching every step is how the rounds reached the crossing's
#     alone target here (one draw); no default changes (coaching is a person's input, the paper's protocol is takeovers
#     only). Primary holds, a guard fails: the trade, reported. Primary fails: reported.
#   Not finished by 09:30 UTC: the finished seeds, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== C1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc docs/results.md --out results/cycles-small-coach-all --section cycles-coach-all --set study.coach_share=1.0
echo "== rc=$? end $(date -u +%FT%T)"

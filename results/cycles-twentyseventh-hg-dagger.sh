#!/bin/bash
# Issue 62, twenty-seventh session (2026-12-01, written 08:09 UTC, before any run of it): a diagnosis, not a candidate.
# At 30,000 steps HG-DAgger drives the crossing alone in 99% and SAGE in 43%; IBRL's clone of SAGE's takeovers in
# 61% (docs/notes/ugv_budget.md). In the cycles the rounds hold UGV 3 alone at 0.72 on this host (0.84 on the Intel
# host) against issue 62's 0.90, whatever anchor was added. The question: is it the learner (SAGE's RL terms) or the
# takeover data that holds the rounds under the target? Arm H: the same rounds, the same starting weights, world model
# and gate (policies/ugv-default relabelled as trained by hg-dagger, results/as_method.py, runs/ugv-default-as-hg-dagger),
# with --set finetune.adapt_as_sage=false, so every round trains HG-DAgger (imitation of the takeovers only, no critic)
# on exactly what SAGE's rounds get; every other setting the defaults; sage's trial name, five seeds, UGV 3; against the
# control run at 3e44520 on this host (results/cycles-small-defaults-27), paired by seed.
# Reading, decided now:
#   alone_success_last mean >= 0.90 with at most one seed lower than its control seed -> "imitation-only rounds reach
#     the target from the same takeovers: SAGE's RL terms hold the rounds under it" (a measured cause, one draw);
#   mean above the control's + 0.10, under 0.90 -> "imitation-only rounds do better, short of the target";
#   mean within the control's +- 0.10 -> "not the learner: the takeover data holds the rounds under the target";
#   mean below the control's - 0.10 -> "the RL terms help the rounds here".
#   Beside, not deciding: takeover_last, static_success_last, unseen_success_last, collision cycles. No default changes
#   (the product's rounds stay SAGE, issue 62 item 1). Not finished by 09:30 UTC: the finished seeds, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
[ -f runs/ugv-default-as-hg-dagger/checkpoint.pt ] || .venv/bin/python results/as_method.py policies/ugv-default hg-dagger runs/ugv-default-as-hg-dagger
echo "== H3 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc docs/results.md --out results/cycles-small-hg-dagger-rounds --section cycles-hg-dagger-rounds \
  --set study.policy=runs/ugv-default-as-hg-dagger --set finetune.adapt_as_sage=false
echo "== rc=$? end $(date -u +%FT%T)"

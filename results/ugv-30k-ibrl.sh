#!/bin/bash
# Issue 62, twenty-seventh session (2026-12-01), written 07:30 UTC after arm I of the cycles (results/cycles-
# twentyseventh-ibrl.sh) and before this run: a second attribution of the UGV study's reading that goes against the
# paper. At 30,000 steps SAGE drives scenario 3 (the crossing) alone in 43% of episodes (per seed 100, 65, 25, 15,
# 10), HG-DAgger in 99% (-56 [-103, -9] points), under the same gate and expert; ten times the imitation weight left
# it undecided (60%, +17 [-65, +99]). The hypothesis this tests: SAGE's RL actor does not hold what a clone of the
# same takeovers holds. Arm: SAGE with IBRL (--set learner.ibrl=true --set learner.ibrl_refit_every=1000): π_IL,
# HG-DAgger's clone of the takeovers so far (1,000 updates every 1,000 environment steps: one update per step, as
# HG-DAgger's updates_per_step = 1; chosen now, not tuned), proposes beside the RL actor when acting (also alone) and
# in the TD target; no other change; five seeds, the 30,000-step study, this host kind (an AMD EPYC, as the row it is
# read against).
# Reading, decided now: the arm's scenario-3 success minus the 30,000-step SAGE row's (results/ugv-30k), paired by
# seed, 95% t-interval: wholly above 0 and the arm's mean >= 80% -> "a clone of the takeovers proposing beside the RL
# actor carries the deficit" (measured cause); wholly above 0 with a mean under 80% -> "part of it"; straddling 0 ->
# undecided; wholly below -> "not what IBRL's proposals add". Scenarios 1, 2 and 4 reported beside it; and, beside it,
# not deciding it, the share of steps π_IL acts alone and the same versions' RL actors alone. No default changes with
# it. Not finished by 08:40 UTC -> the finished seeds reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== ugv-30k-ibrl start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study ugv --budget small --train-steps 30000 --cpus 2 --max-concurrent 2 --methods sage \
  --set learner.ibrl=true --set learner.ibrl_refit_every=1000 --out results/ugv-30k-ibrl --section ugv-30k-ibrl \
  --results-doc docs/results.md
echo "== ugv-30k-ibrl rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"

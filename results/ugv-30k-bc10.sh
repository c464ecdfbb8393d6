#!/bin/bash
# Issue 62, twenty-sixth session (2026-12-01), written 06:05 UTC after results/ugv-30k.sh's reading and before this
# run: an exploratory attribution of the one reading there that goes against the paper. At 30,000 steps SAGE drives
# scenario 3 (the crossing) alone in 43% of episodes (per seed 100, 65, 25, 15, 10), HG-DAgger in 99% (paired
# difference -56 [-103, -9] points), though both learn under the same gate from the same scripted expert's takeovers
# (HG-DAgger: aggregated imitation of them only; SAGE: fear-regularised SAC with value-weighted imitation of them, its
# rounds' mean omega 1.03-1.13 here, so the weighting keeps the takeovers). The hypothesis it tests: the RL terms
# outweigh the imitation on the crossing. Arm: SAGE alone with ten times the imitation weight (--set
# learner.bc_weight=10, the fourteenth session's arm Omega value; no other change), five seeds, the 30,000-step study.
# Reading, decided now: SAGE x10's scenario-3 success minus the 30,000-step SAGE row's, paired by seed, 95% t-interval:
# wholly above 0 and the arm's mean >= 80% -> "the imitation's weight against the RL terms carries the deficit"
# (measured cause); wholly above 0 with a mean under 80% -> "part of it"; straddling 0 -> undecided; wholly below ->
# "not the imitation's weight". Scenarios 1, 2 and 4 reported beside it. No default changes with it. Not finished by
# 06:55 UTC -> the finished seeds reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== ugv-30k-bc10 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study ugv --budget small --train-steps 30000 --cpus 2 --max-concurrent 2 --methods sage \
  --set learner.bc_weight=10 --out results/ugv-30k-bc10 --section ugv-30k-bc10 --results-doc docs/results.md
echo "== ugv-30k-bc10 rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"

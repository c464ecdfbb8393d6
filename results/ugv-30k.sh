#!/bin/bash
# Issues 62 (item 6: "the other studies at a budget that decides ... the UGV table with adaptation from the default
# policy") and 63 ("every study here stops at budgets too small to decide the paper's direction on the UGV"),
# twenty-sixth session (2026-12-01). The UGV study (all nine methods, five seeds, the same warm start) at 30,000
# environment steps a method and seed, five times the small budget's 6,000: the budget at which the route-shift study's
# learners learned route 1 (docs/notes/route_shift_budget.md), never run on the UGV. This session's host (AMD EPYC,
# `studies.host_speed` 2,966 UGV steps/s, 269 SAC updates/s; ~3.5x the AMD host of the thirteenth session) makes it
# fit: estimated from the fifteenth session's trial-minutes ~70 trial-min, ~35-45 min wall on two cores.
#
# Reading, written before the run (04:47 UTC), by results/ugv_budget_read.py from the two folders' seeds.csv:
# 1. Per scenario 1-4, SAGE's success minus each other learner's (sac, td3, hg-dagger, multi-hug, diffusion-bc,
#    diffusion-ql), paired by seed (the same evaluation episodes), 95% t-interval over the five seeds: wholly above 0
#    -> "the paper's direction, decided"; wholly below -> "against the paper, decided"; otherwise undecided. Read at
#    30,000 steps and, from the committed small table (results/ugv-small-fifteenth, 6,000 steps, an Intel host), at
#    6,000 beside it.
# 2. Warm-start collapse: each learner's success on the static scenarios 1-2 at 30,000 against 6,000 (the default
#    policy alone drives them without a collision); said as measured, rising or not.
# 3. SAGE against the paper's 100% on every scenario: its mean and interval, said as measured.
# Nothing is tuned on these rows; no default changes with them. Not finished by 07:00 UTC -> the finished trials are
# kept (the study resumes from results/ugv-30k/trials) and reported as unfinished, with what was measured.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== ugv-30k start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m studies.host_speed
.venv/bin/python -m app.cli study ugv --budget small --train-steps 30000 --cpus 2 --max-concurrent 2 \
  --out results/ugv-30k --section ugv-30k --results-doc docs/results.md
echo "== ugv-30k rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python results/ugv_budget_read.py results/ugv-small-fifteenth results/ugv-30k > results/ugv-30k-read.md

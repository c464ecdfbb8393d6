#!/bin/bash
# Twelfth session (2026-11-29): a check of the promotion's new progress test (core/promotion.py, 514b5ea) on the
# situation that motivated it, not an arm for adoption: arm K's rounds (finetune.round_keep=0.25, UGV 3, five seeds),
# whose seed 1 line stalled from cycle 5 (supervised success 0, takeover 0-4%, alone 7 of 10 timeouts), now with the
# live worker's promotion (study.promotion=true: collisions, progress, takeover, 15 paired episodes a version).
# Expected, written before the run: on seed 1 the stalled versions are refused with the progress reason ("reached the
# goal in ..."), so the line in control at the end does not stall (alone timeouts of the last cycle's version below
# K's 0.7 on seed 1). Reported either way; nothing is chosen from it. Not finished by 20:50 UTC: what finished.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== progress check start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 2 --max-concurrent 2 \
  --results-doc docs/results.md --out results/cycles-small-keep-quarter-promotion --methods sage \
  --set finetune.round_keep=0.25 --set study.promotion=true --section cycles-keep-quarter-promotion
echo "== rc=$? end $(date -u +%FT%T)"

#!/bin/bash
# Issue 62, ninth session (2026-11-29): arm P, the cycles study with the live worker's promotion (the supervised
# tests: a version drives only if, on 15 paired episodes of the cycle's scenario with gate and expert, it collides
# in no more episodes than the version in control and asks for less help at least as often as for more), UGV 3,
# sage only, paired by seed against results/cycles-small-defaults (section cycles-defaults), present defaults.
# The live server promotes this way by default; the study's default lets every version drive.
# Rule, written before the run (committed with this script):
#   primary: collision_cycles_above_first summed over the five seeds = 0 (the target: no cycle with more supervised
#   collisions than the first; cycles-defaults: 2 of 5 seeds have such cycles);
#   guards: alone_success_last mean >= 0.75, takeover_last mean <= 0.12, static_success_last mean >= 0.80.
#   All hold: the cycles study's default promotion becomes the live worker's (study.promotion=true), so that it
#   measures what the product deploys. Primary fails: reported, not adopted. A guard fails: the trade, reported.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== promotion start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 \
  --results-doc docs/results.md --out results/cycles-small-promotion-defaults --methods sage \
  --set study.promotion=true --section cycles-promotion-defaults
echo "== rc=$? end $(date -u +%FT%T)"

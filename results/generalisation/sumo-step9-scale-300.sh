#!/usr/bin/env bash
# Issue 60, twenty-fifth session (2026-12-01): is step 9's operating point a stable choice on training ground?
# Written 03:37 UTC, after the warm-pool ablation (docs/notes/generalisation.md, "Twenty-fifth session": the operating
# point, not the varied traffic, carries step 9's unseen gain), before any run of this.
# Why: step 9's gate.tau_scale=0.7 was chosen by `sage gate choose-scale` at 100 episodes a training scenario, where
# scale 1 missed on c2 with 8 of 100 (the plain pool's 4 of 100 kept 1): a count the 100 episodes do not decide, on
# which the unseen gain now rests. The issue asks for >= 300 episodes a row.
# Run: the same command at 300 episodes on c1 and c2 (the default grid; choose-scale takes the largest scale meeting
# <= 5% with a violation at <= 35% takeover on both). Nothing reads a test seed.
# Reading, decided now: it chooses 0.7: step 9's operating point is confirmed at the issue's size. It chooses another
# scale s: reported, and the note says that the operating point carrying SUMO's unseen gain is not stable at the
# rule's size; no default changes this session (another operating point is adopted only by the standing rule: the
# unseen, seen and four built-in rows). Not finished by 04:40 UTC: not measured.
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1
out=results/generalisation
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): choose-scale on c1, c2 at 300 episodes"
  .venv/bin/sage gate choose-scale policies/sumo-default --sim sumo --scenario c1 --scenario c2 --episodes 300 \
      --cpus 2 --out $out/sumo-step9-scale-300.json
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a $out/sumo-step9-scale-300.log

#!/bin/bash
# Issue 62, ninth session (2026-11-29): arm Q, practice alone in the rounds (finetune.practice_episodes=3: before each
# round the version in control drives three episodes of the cycle's scenario alone in simulation, collisions
# included, into the round's buffer). Why: the route-shift probe (docs/notes/route_shift_budget.md) found that being
# supervised is what keeps SAGE's policy from driving alone: the agent's action is replaced where fear is high, so
# the critic never sees what it led to. Three episodes: about one cycle's deployment (666 steps, 2-5 episodes).
# sage only, five seeds, the present defaults otherwise; Q3 on UGV 3 paired against results/cycles-small-defaults,
# Q4 on UGV 4 against results/cycles-small-ugv4-defaults. Rule, written before the run (committed with this script):
#   Q3 primary: alone_success_last mean >= 0.90 (the target) and its paired mean over seeds above cycles-defaults'
#     (0.82); guards: takeover_last mean <= 0.12, static_success_last mean >= 0.80, collision_cycles_above_first
#     summed over seeds <= cycles-defaults' (4).
#   Q4 (confirmation, run whatever Q3 shows): the same against cycles-ugv4-defaults (alone 0.88; collision cycles 2).
#   Both hold: practice_episodes=3 becomes the fine-tuning default (worker and studies). Q3 holds and Q4 does not:
#   reported, not adopted. Q3 fails: not a remedy at this size.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  shift
  nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set finetune.practice_episodes=3 "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
run Q3 --out results/cycles-small-practice --section cycles-practice
run Q4 --out results/cycles-small-ugv4-practice --set study.scenario=4 --section cycles-ugv4-practice

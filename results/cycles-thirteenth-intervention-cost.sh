#!/bin/bash
# Issue 62, thirteenth session (2026-11-29): arm I, the takeover as a cost on the action that brought it (--set
# learner.intervention_penalty=10: the agent's own transition just before each takeover onset loses 10 reward in the
# rounds' buffer; Multi-Hug's intervention-based shaping, RLIF's intervention as the learning signal). Why: under
# the gate the expert replaces the agent's action where fear is high, so no round's critic ever sees that entering
# such a state is bad (docs/notes/route_shift_budget.md; issue 62: "the critic never sees a failure"), and on the
# unseen two-mover field the versions drift into states that ask for help more each cycle (takeover 0.30 -> 0.54).
# The cost is the gate's own judgement turned into a failure the critic learns from, without a robot crashing (item
# 3). Not the paper's SAGE (it has no such term); off by default. The value 10 is Multi-Hug's in this project (the
# UGV reward: 10 per metre of progress, -100 a collision, +100 the goal), chosen before the run, not tuned.
# sage only, five seeds, the present defaults otherwise. Resumable (rerun with the same argument).
#   I3: UGV 3, paired by seed against results/cycles-small-defaults (alone 0.82, unseen UGV 4 0.70, takeover last
#     0.089, static 0.86, collision cycles 4).
#   I-fields: ugv-fields:test:1 (unseen test:4), against results/cycles-small-fields-defaults (alone 0.60, takeover
#     first 0.303, last 0.539, static 0.59).
# Rule, written before the run (committed with this script):
#   I-fields primary: takeover_last mean <= 0.303 (no rise over the first cycle). Guards: alone_success_last mean >=
#     0.60, static_success_last mean >= 0.59.
#   I3 primary: alone_success_last mean >= 0.82 with at most one seed lower than its control seed, and takeover_last
#     mean <= 0.089. Guards: static_success_last mean >= 0.80, unseen_success_last mean >= 0.60,
#     collision_cycles_above_first summed <= 4.
#   A seed whose last version stands still (alone: 5 or more of 10 episodes time out) is named, whatever the verdict.
#   Both primaries and every guard hold: the intervention cost becomes a fine-tuning default (a departure from the
#   paper's SAGE, said so wherever the rounds' method is named). One arm's primary holds: the trade, reported, not
#   adopted. Neither: not the lever; reported. Not finished by 22:50 UTC: the seeds that finished are reported,
#   undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?3 or fields}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  shift
  nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set learner.intervention_penalty=10 "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  3) run I3 --out results/cycles-small-intervention-cost --section cycles-intervention-cost ;;
  fields) run I-fields --out results/cycles-small-fields-intervention-cost --set study.scenario=ugv-fields:test:1 \
    --set study.unseen_scenario=ugv-fields:test:4 --section cycles-fields-intervention-cost ;;
esac

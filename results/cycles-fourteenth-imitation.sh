#!/bin/bash
# Issue 62, fourteenth session (2026-11-30): arm Ω, ten times the imitation weight in the rounds (--set
# learner.bc_weight=10; the UGV default's 1.0). Why: alone on UGV 3 the present defaults plateau after the first
# round (mean alone after cycles 1-9: 0.10, 0.68, 0.70, 0.76, 0.78, 0.64, 0.76, 0.78, 0.82), and every alone failure
# of the last versions is a collision (seeds 0-4's v0008 on the ten alone seeds: 1, 1, 4, 1, 2 collisions, no
# timeout; the scripted expert drives all ten), i.e. in the states where, supervised, the gate hands over and the
# expert's takeover is recorded. What the rounds learn there is the imitation term's: its weight is the one lever of
# issue 62's first probe (one seed: ten times the imitation weight 0 -> 5 -> 5/10 alone against 0 -> 4 -> 4/10) that
# no five-seed arm has measured. 10 is that probe's value, chosen before this run, not tuned. The paper's SAGE (its
# imitation term, another weight). sage only, five seeds, the present defaults otherwise. Resumable.
#   Ω3: UGV 3, paired by seed against results/cycles-small-defaults (alone 0.82, unseen UGV 4 0.70, takeover last
#     0.089, static 0.86, collision cycles 4).
#   Ω-fields: ugv-fields:test:1 (unseen test:4), against results/cycles-small-fields-defaults (alone 0.60, takeover
#     first 0.303, last 0.539, static 0.59).
# Rule, written before the run (committed with this script):
#   Ω3 primary: alone_success_last mean >= 0.90 (issue 62's target) with at most one seed lower than its control seed.
#     Guards: takeover_last mean <= 0.10, static_success_last mean >= 0.81, unseen_success_last mean >= 0.60,
#     collision_cycles_above_first summed <= 4.
#   Ω-fields guards (imitating harder must not break the unseen field): takeover_last mean <= 0.539, alone_success_last
#     mean >= 0.60, static_success_last mean >= 0.54.
#   Ω3's primary and every guard of both hold: bc_weight=10 becomes the rounds' default (FinetuneConfig overrides),
#   after the pre-registered confirmation on UGV 4 (run as `4`, against results/cycles-small-ugv4-defaults: alone
#   >= 0.90 with at most one seed lower, takeover_last <= 0.10, static >= 0.81). Ω3's primary holds, a guard fails:
#   the trade, reported, not adopted. Ω3's primary fails: not the lever; reported (with the per-cycle alone line, to
#   say whether the plateau moved). Not finished by 01:40 UTC: the seeds that finished are reported, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?3, fields or 4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  shift
  nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set learner.bc_weight=10 "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  3) run Ω3 --out results/cycles-small-imitation --section cycles-imitation ;;
  4) run Ω4 --out results/cycles-small-ugv4-imitation --set study.scenario=4 \
    --section cycles-ugv4-imitation ;;
  fields) run Ω-fields --out results/cycles-small-fields-imitation --set study.scenario=ugv-fields:test:1 \
    --set study.unseen_scenario=ugv-fields:test:4 --section cycles-fields-imitation ;;
esac

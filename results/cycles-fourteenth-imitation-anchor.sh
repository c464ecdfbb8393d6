#!/bin/bash
# Issue 62, fourteenth session (2026-11-30): arm ΩA, the rounds' two supervised terms both ten times their default
# (--set learner.bc_weight=10 --set finetune.prior_distill=5: imitation of the takeovers and the anchor on the base's
# drives keep the defaults' ratio, and both weigh ten times as much against the RL term). Written at 01:06 UTC, AFTER
# arm Ω (bc_weight=10 alone, results/cycles-fourteenth-imitation.sh) was seen: Ω3 failed its primary (alone 0.78,
# static 0.36 against 0.86: the imitation pulled the actor off the static scenarios), while on the unseen field every
# seed drove it alone (1.0 against 0.60, takeover last 0.445 against 0.539, static 0.53 against 0.59). The question:
# does the anchor scaled with the imitation keep the static scenarios and Ω's gain on the field? The ten is Ω's, not
# tuned. sage only, five seeds, the present defaults otherwise. Resumable.
#   ΩA3: UGV 3, paired by seed against results/cycles-small-defaults (alone 0.82, unseen 0.70, takeover last 0.089,
#     static 0.86, collision cycles 4).
#   ΩA-fields: ugv-fields:test:1 (unseen test:4), against results/cycles-small-fields-defaults (alone 0.60, takeover
#     first 0.303, last 0.539, static 0.59).
# Rule, written before the run (committed with this script):
#   ΩA3 primary: alone_success_last mean >= 0.90 with at most one seed lower than its control seed. Guards:
#     static_success_last mean >= 0.81, takeover_last mean <= 0.10, unseen_success_last mean >= 0.60,
#     collision_cycles_above_first summed <= 4.
#   ΩA-fields primary: alone_success_last mean >= 0.80 and static_success_last mean >= 0.59. Guard: takeover_last mean
#     <= 0.539.
#   Both primaries and every guard hold: a candidate default, adopted only after the UGV 4 confirmation (alone >= 0.90,
#   static >= 0.81, takeover <= 0.10 against results/cycles-small-ugv4-defaults), which this session runs only if time
#   is left (else: a candidate, unconfirmed, nothing changed). ΩA-fields' primary alone holds: reported as the field's
#   lever, with UGV 3's cost. Neither: not the lever. Not finished by 01:40 UTC: the seeds that finished, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?3, fields or 4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  shift
  nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set learner.bc_weight=10 --set finetune.prior_distill=5 "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  3) run ΩA3 --out results/cycles-small-imitation-anchor --section cycles-imitation-anchor ;;
  4) run ΩA4 --out results/cycles-small-ugv4-imitation-anchor --set study.scenario=4 \
    --section cycles-ugv4-imitation-anchor ;;
  fields) run ΩA-fields --out results/cycles-small-fields-imitation-anchor --set study.scenario=ugv-fields:test:1 \
    --set study.unseen_scenario=ugv-fields:test:4 --section cycles-fields-imitation-anchor ;;
esac

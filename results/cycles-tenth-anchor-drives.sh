#!/bin/bash
# Issue 62, tenth session (2026-11-29): arm S, the anchor's drives learned from (finetune.anchor_drives_learn=true:
# the version's drives of the prior situations, made before every round for the anchor_relabel default, also join the
# buffer's prior part as its own steps, collisions included). Why (docs/notes/forgetting_anatomy.md): the base's
# static skill breaks under a turn bias of 0.05, the rounds' RL part moves the turn command most, and the critic never
# sees what that drift leads to on static ground (the prior rows are the base's successes); here it does, with no
# extra simulation. sage only, five seeds, the present defaults otherwise: S3 on UGV 3 paired by seed against
# results/cycles-small-defaults, S4 on UGV 4 against results/cycles-small-ugv4-defaults (the code path of both
# controls is unchanged since: b2fe1a5, a2dd844 and f789f5d change no training round).
# Rule, written before the run (committed with this script):
#   primary, per arm (forgetting): static_success_last mean paired gain >= +0.07 (control 0.86 on both), with at
#     most one seed of five lower than its control seed.
#   guards, per arm: alone_success_last mean >= control - 0.05 (S3 >= 0.77, S4 >= 0.83); takeover_last mean <= 0.10;
#     collision_cycles_above_first summed over seeds <= control's + 1 (S3 <= 5, S4 <= 3).
#   Both arms hold everything: anchor_drives_learn=true becomes the fine-tuning default. One arm: reported, not
#   adopted. Primary not met on S3: not a remedy at this size. Not finished by 16:05 UTC: not measured, with the
#   trials that finished.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?S3 or S4}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  shift
  nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set finetune.anchor_drives_learn=true "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  S3) run S3 --out results/cycles-small-anchor-drives --section cycles-anchor-drives ;;
  S4) run S4 --out results/cycles-small-ugv4-anchor-drives --set study.scenario=4 --section cycles-ugv4-anchor-drives ;;
esac

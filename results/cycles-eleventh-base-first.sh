#!/bin/bash
# Issue 62, eleventh session (2026-11-29): arm B, let the base drive first again (--set finetune.base_first=true: a
# version acts as v0000 wherever its gate, watching v0000's action, would not ask for help, and its own actor acts
# where it would). Why again: measured in the fifth session (results/cycles-small-base-first) it kept more of the
# static scenarios (+10.4 of 40 a seed) but lost alone on UGV 3 (0.62) and transfer to UGV 4 (0.08), with a gate that
# then asked for help on 28.6% of UGV 1's steps (docs/notes/oracle_gate_ugv, at 8a6268e); the gate deployed since
# (mover model, contact over 10 steps, disagreement curiosity) asks for help on 1.7% of UGV 1's steps (this session,
# 10 episodes, exploratory), so the watch now hands control to the version far more selectively: where the base is
# out of its depth. sage only, five seeds, the present defaults otherwise. Resumable (rerun with the same argument).
#   B3: UGV 3, paired by seed against results/cycles-small-defaults (alone 0.82, unseen UGV 4 0.70, takeover last
#     0.089, static 0.86, collision cycles 4).
#   B-fields: ugv-fields:test:1 (unseen test:4), against results/cycles-small-fields-defaults (alone 0.60, takeover
#     last 0.539, static 0.59).
# Rule, written before the run (committed with this script):
#   B3 primary: static_success_last mean >= 0.95 (issue 62: scenarios 1-2 alone no worse than the default's 1.00;
#     control 0.86) and alone_success_last mean >= 0.77 (the control's 0.82 - 0.05).
#   B3 guards: takeover_last mean <= 0.10, unseen_success_last mean >= 0.60 (control 0.70 - 0.10),
#     collision_cycles_above_first summed <= 5.
#   B-fields guards: alone_success_last mean >= 0.60, takeover_last mean <= 0.589, static_success_last mean >= 0.54.
#   All hold: base_first=true becomes the fine-tuning default. B3's primary holds and a guard fails: the trade,
#   reported, not adopted. B3's primary fails: the quieter gate does not make the switch keep the static scenarios and
#   the crossing at once; reported. Not finished by 18:50 UTC: not measured, with the trials that finished.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?3 or fields}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
  shift
  nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set finetune.base_first=true "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  3) run B3 --out results/cycles-small-base-first-quiet --section cycles-base-first-quiet ;;
  fields) run B-fields --out results/cycles-small-fields-base-first --set study.scenario=ugv-fields:test:1 \
    --set study.unseen_scenario=ugv-fields:test:4 --section cycles-fields-base-first ;;
esac

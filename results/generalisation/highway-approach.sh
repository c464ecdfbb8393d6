#!/usr/bin/env bash
# Issue 60, twenty-second session (2026-11-30): highway's world model with each beam's approach rate (inverse time to
# contact) as an input, fitted afresh on train ground. Plan and rule in docs/notes/generalisation.md ("Twenty-second
# session: each beam's time to contact as an input of highway's world model"), written before this run.
# Stage A, one refit and its unseen ranking:  bash highway-approach.sh A SEED
#   (the committed default's ranking on the same 100 episodes: highway-approach-committed.{md,json})
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
stage=$1
S=$2
out=results/generalisation
log=$out/highway-approach-s$S.log
fit=runs/highway-approach-s$S
{
if [ "$stage" = A ]; then
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): seed $S world model with approach rates, 600 + 40"
  .venv/bin/sage train --sim highway --scenario train --init policies/highway-default --world-model-only \
      --episodes 600 --demo-episodes 40 --demo-noise 0.3 --seed "$S" \
      --set world_model_config.approach_start=11 --set world_model_config.approach_stop=83 \
      --checkpoint-every 0 --checkpoint-dtype float16 --quiet --out "$fit"
  echo "== $(date -u +%H:%M:%S): unseen signals, 100 episodes"
  $PY -m studies.generalisation --sim highway --run "$fit" --episodes 100 --gate-episodes 0 --grounds unseen \
      --out $out/highway-approach-s$S-a.md --cache $out/highway-approach-s$S.json
  echo "== $(date -u +%H:%M:%S): stage A done for seed $S"
fi
} 2>&1 | tee -a "$log"

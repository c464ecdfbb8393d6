#!/usr/bin/env bash
# Issue 60, twenty-fourth session: the ablation sumo-varied.sh leaves open (descriptive; decides no default).
# sumo-varied.sh's refits are fresh five-member fits on c1, c2 and the varied splits; the committed world model is a
# lineage of warm refits on more data. Its merged candidate ranked unseen danger lower (0.936 against the committed
# 0.964), which may be the variation's or the fresh fits'. Here the same five fresh fits on c1 and c2 alone (the same
# budget, seeds, label and gate), each read on the same 100 unseen episodes as the varied refits.
# Reading, written before the run: variation helps the ranking if the varied refits' mean unseen fear AUROC exceeds
# the plain ones' by at least 0.01 with the varied refit higher in at least 4 of the 5 seeds; it hurts by the mirror
# rule; otherwise undecided at this size.
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
export OMP_NUM_THREADS=1
out=results/generalisation
log=$out/sumo-plain-fresh.log
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): five fresh five-member refits on c1, c2"
  for pair in "0 1" "2 3" "4"; do
    for s in $pair; do
      .venv/bin/sage train --sim sumo --scenario c1,c2 --init policies/sumo-default --world-model-only --episodes 150 \
          --seed "$s" --demo-episodes 10 --demo-noise 0.3 --set world_model_config.members=5 --checkpoint-every 0 \
          --checkpoint-dtype float16 --quiet --out runs/sumo-plain-fresh-s"$s" &
    done
    wait
  done
  echo "== $(date -u +%H:%M:%S): each refit's unseen ranking (100 episodes, no gate rows)"
  for pair in "0 1" "2 3" "4"; do
    for s in $pair; do
      $PY -m studies.generalisation --sim sumo --run runs/sumo-plain-fresh-s"$s" --episodes 100 --gate-episodes 0 \
          --grounds unseen --out $out/sumo-plain-fresh-s"$s".md --cache $out/sumo-plain-fresh-s"$s".json &
    done
    wait
  done
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a "$log"

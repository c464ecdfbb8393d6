#!/usr/bin/env bash
# Issue 60, twenty-fourth session (2026-11-30): SUMO's world model fitted on traffic that varies (domain
# randomisation), measured on sumo-shift:test. Plan and rule written here before any run of it (also in
# docs/notes/generalisation.md, "Twenty-fourth session").
#
# Why: on sumo-shift:test the gate + scripted expert leave 35 of 300 episodes with a violation (12%) at 16% takeover,
# the expert alone drives it without one, and half the violations come with fear under tau_min throughout; traced
# (sixteenth session), the ramp's rear-end collisions come with every member imagining the close, slow leader pulling
# away, as C1's and C2's vehicles mostly did. Neither a floor (imagined contact), a threshold nor the closing
# extrapolation changed that; what the notes left is the model's view of vehicles with other habits. The issue lists
# "more diverse training fields" as a way to transfer, with models fitted on training ground only.
#
# Candidate V: five refits of policies/sumo-default's world model (the committed recipe of its README step 5: 150
# policy episodes and 10 noisy demonstrations each, seeds 0-4, the same label and gate) whose episodes go in turn over
# c1, c2 and the two varied training splits (sims/sumo/variation.py: each episode six special-vehicle flows of random
# type on its route's own flows' edges and a density drawn in 0.7-1.5; route 1 and route 2, nothing from route 3's
# files), merged into one 25-member ensemble (step 6's `sage gate merge`: tau bounds on the union of the refits'
# calibration states), its operating point chosen on c1 and c2 by the committed procedure (`sage gate choose-scale`,
# 100 episodes each, default grid). The data budget equals the committed refits' (150 episodes each). No test seed
# chooses anything; the ranges were set before any run and are not changed after it.
# Baseline B: policies/sumo-default as committed; its generalisation rows from docs/generalisation.md (regenerated at
# 0908da6, the same seeds), its built-in rows driven again now beside the candidate's.
#
# Rule (the standing one, as sumo-contact.sh's): V is adopted into policies/sumo-default only if all hold, with
# core.metrics.difference_interval (V minus B):
#  1. sumo-shift:test, gate + scripted expert, 300 episodes: the 95% interval of the difference in the share of
#     episodes with a violation lies wholly below 0, at a takeover no more than 5 points above B's and at most 35%
#     (or, at an equal share, takeover lower by at least 5 points);
#  2. seen ground (c1, c2), 300 episodes: the interval does not lie wholly above 0, takeover at most 5 points above B's;
#  3. the built-in gate rows (c1, c2, 2, 1-special; 300 episodes each): per scenario the interval does not lie wholly
#     above 0, takeover at most 5 points above B's.
# Reported beside it, not deciding: fear and curiosity AUROC on both grounds, firing, the merged tau bounds, and the
# five refits' unseen fear AUROC one by one (the spread over refits; their gate rows are not measured).
# A stage not finished by 02:15 UTC (2026-12-01) is reported as not measured, with no verdict.
#
# Corrected 00:26 UTC, before any candidate result existed (the first launch stopped in choose-scale's first rows):
# refits warm-started from policies/sumo-default hold its 25 members each, so their merge held 125, not the 25 the
# plan states (the committed refits started from a 5-member model). The refits now set world_model_config.members=5;
# a 25-member checkpoint cannot warm a 5-member model, so each is a fresh fit on its 150 episodes (the policy warm).
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
export OMP_NUM_THREADS=1
out=results/generalisation
log=$out/sumo-varied.log
stage=${1:-all}
{
  if [[ $stage == all || $stage == refits ]]; then
    echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): five refits on c1, c2 and the varied splits"
    for pair in "0 1" "2 3" "4"; do
      for s in $pair; do
        .venv/bin/sage train --sim sumo --scenario c1,c2,sumo-shift:varied1,sumo-shift:varied2 \
            --init policies/sumo-default --world-model-only --episodes 150 --seed "$s" --demo-episodes 10 \
            --demo-noise 0.3 --set world_model_config.members=5 --checkpoint-every 0 --checkpoint-dtype float16 \
            --quiet --out runs/sumo-varied-s"$s" &
      done
      wait
    done
    echo "== $(date -u +%H:%M:%S): merge"
    .venv/bin/sage gate merge runs/sumo-varied-s0 runs/sumo-varied-s1 runs/sumo-varied-s2 runs/sumo-varied-s3 \
        runs/sumo-varied-s4 --out runs/sumo-varied-merged --checkpoint-dtype float16
  fi
  if [[ $stage == all || $stage == scale ]]; then
    echo "== $(date -u +%H:%M:%S): choose-scale on c1, c2 (the committed procedure's grid and episodes)"
    .venv/bin/sage gate choose-scale runs/sumo-varied-merged --sim sumo --scenario c1 --scenario c2 --episodes 100 \
        --cpus 2 --out $out/sumo-varied-scale.json
  fi
  if [[ $stage == all || $stage == tables ]]; then
    scale=$($PY -c "import json; print(json.load(open('$out/sumo-varied-scale.json'))['scale'])")
    echo "== $(date -u +%H:%M:%S): chosen scale $scale; generalisation table (300 + 300) and built-in rows"
    $PY -m studies.generalisation --sim sumo --run runs/sumo-varied-merged --episodes 300 --gate-episodes 300 \
        --set gate.tau_scale="$scale" --out $out/sumo-varied.md --cache $out/sumo-varied.json &
    { $PY $out/builtin_rows.py sumo runs/sumo-varied-merged $out/sumo-varied-builtin-rows.json tau_scale="$scale"
      $PY $out/builtin_rows.py sumo policies/sumo-default $out/sumo-baseline-24-builtin-rows.json; } &
    wait
    echo "== $(date -u +%H:%M:%S): the rule's reading"
    $PY -m experiments.generalisation_rule --sim sumo --candidate runs/sumo-varied-merged \
        --candidate-cache $out/sumo-varied.json --candidate-set gate.tau_scale="$scale" \
        --baseline policies/sumo-default --baseline-table docs/generalisation.md \
        --unseen sumo-shift:test --seen c1,c2 --episodes 300 --seen-episodes 300 || true
    PYTHONPATH=. $PY $out/builtin_compare.py $out/sumo-varied-builtin-rows.json $out/sumo-baseline-24-builtin-rows.json || true
  fi
  if [[ $stage == all || $stage == spread ]]; then
    echo "== $(date -u +%H:%M:%S): each refit's unseen ranking (100 episodes, no gate rows)"
    for s in 0 1 2 3 4; do
      $PY -m studies.generalisation --sim sumo --run runs/sumo-varied-s"$s" --episodes 100 --gate-episodes 0 \
          --grounds unseen --out $out/sumo-varied-s"$s".md --cache $out/sumo-varied-s"$s".json
    done
  fi
  echo "== $(date -u +%H:%M:%S): done $stage"
} 2>&1 | tee -a "$log"

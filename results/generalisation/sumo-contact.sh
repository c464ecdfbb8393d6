#!/usr/bin/env bash
# Issue 60, sixteenth session (2026-11-30): imagined contact on SUMO's leader channel, the mechanism that carries the UGV
# gate's transfer, measured against the committed SUMO default on the same seeds. Rule written before any run (below
# and in docs/notes/generalisation.md, "Sixteenth session").
#
# Why: on sumo-shift:test the gate + scripted expert leave 35 of 300 episodes with a violation (12%) at 16% takeover,
# while the expert alone drives the route without one; traced on 100 of those episodes at f44a844 (scratch, not a
# decision): all 10 violations are collisions with the ego as the collider, 6 of them rear-ending a slower or stopped
# leader on one ramp (rb1_to_s1; three the route's bus) with the leader channel at 0.023-0.051 (4.6-10 m centre to
# centre) on the step before, fear 0.0-0.2 against tau 0.15-0.34; 4 at junctions with crossing traffic.
#
# Candidate C: the committed default's gate with gate.imagined_contact=true and SUMO's contact floor from its simulator
# (sims.sumo.descriptor.contact_floors: channel 0, the leader's centre distance over the perception range, at or
# under (ego length + car length) / 2 / range = 0.0225: a car ahead touches the ego), the tau bounds measured again
# on its training scenarios with that fear (sage gate refit-bounds, 100 drives of c1 and of c2; the world model's
# weights unchanged: no refit, so no spread over refits to report). Nothing is chosen on a test seed.
# Baseline B: policies/sumo-default as committed, driven now with the same code and seeds.
#
# Rule (the standing one of docs/notes/generalisation.md, "Rule for a later gate change", with the built-in rows):
# C is adopted into policies/sumo-default only if all hold, with core.metrics.difference_interval (C minus B):
#  1. sumo-shift:test, gate + scripted expert, 300 episodes: the 95% interval of the difference in the share of
#     episodes with a violation lies wholly below 0, at a takeover no more than 5 points above B's and at most 35%
#     (or, at an equal share, takeover lower by at least 5 points);
#  2. seen ground (c1, c2), 300 episodes: the interval does not lie wholly above 0, takeover at most 5 points above B's;
#  3. the built-in gate rows (c1, c2, 2, 1-special; 300 episodes each, gate_with_expert, warn 1 s): per scenario the
#     interval does not lie wholly above 0, takeover at most 5 points above B's.
# A run not finished by 07:00 UTC is reported as not measured, with no verdict.
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
mkdir -p runs results/generalisation
log=results/generalisation/sumo-contact.log
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): refit-bounds with imagined contact"
  .venv/bin/sage gate refit-bounds policies/sumo-default --scenario c1,c2 --episodes 100 \
      --set gate.imagined_contact=true --checkpoint-dtype float16 --out runs/sumo-contact
  echo "== $(date -u +%H:%M:%S): generalisation tables, candidate and baseline side by side"
  $PY -m studies.generalisation --sim sumo --run runs/sumo-contact --episodes 300 --gate-episodes 300 \
      --out results/generalisation/sumo-contact.md --cache results/generalisation/sumo-contact.json &
  $PY -m studies.generalisation --sim sumo --episodes 300 --gate-episodes 300 \
      --out results/generalisation/sumo-baseline-16.md --cache results/generalisation/sumo-baseline-16.json &
  wait
  echo "== $(date -u +%H:%M:%S): built-in rows, candidate and baseline side by side"
  $PY results/generalisation/sumo_builtin_rows.py runs/sumo-contact results/generalisation/sumo-contact-builtin-rows.json &
  $PY results/generalisation/sumo_builtin_rows.py policies/sumo-default results/generalisation/sumo-baseline-16-builtin-rows.json &
  wait
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a "$log"

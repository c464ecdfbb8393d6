#!/bin/bash
# Issue 60, eleventh session (2026-11-29): the SUMO default's operating point chosen again on its training scenarios
# at the issue's size. Why: `policies/sumo-default` keeps gate.tau_scale 1 from `sage gate choose-scale` at 100
# episodes a scenario (c1 0 of 100 at 11.6%, c2 5 of 100 at 17.0%: c2 exactly at the 5% target, its interval
# [2%, 11%] undecided), where issue 60 asks for >= 300 episodes a row; on sumo-shift:test the gate + expert row is 35
# of 300 (12%) at 16% takeover. Nothing here reads a test seed: the choice is made on c1 and c2 (the seen ground;
# sumo-shift:train is c2).
# Rule, written before the run (committed with this script):
#   Step 1: `sage gate choose-scale policies/sumo-default --sim sumo --scenario c1 --scenario c2 --episodes 300`
#     (its default scales 1, 0.7, 0.5, 0.35, 0.25; the largest that meets <= 5% with a violation at <= 35% takeover
#     on both). If it chooses 1: the default's operating point is confirmed at 300; nothing changes, stop.
#   Step 2 (only if it chooses s < 1): `studies.generalisation --sim sumo --episodes 300 --gate-episodes 300` with
#     `--set gate.tau_scale=s`, against docs/generalisation.md's SUMO rows (unseen 35 of 300 at 16%, seen 10 of 300
#     at 15%). Adopted into policies/sumo-default (and its generated docs) only if the unseen row's violation share is
#     lower with the 95% interval of the difference (experiments.generalisation_rule) not wholly above 0, the unseen
#     and seen takeover both <= 35%, and the seen row's violations no higher than the baseline's point estimate + 2
#     points. Otherwise reported, not adopted. Not finished by 18:50 UTC: reported as not measured.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/../.."
echo "== step 1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
nice -n 5 .venv/bin/python -m app.cli gate choose-scale policies/sumo-default --sim sumo --scenario c1 --scenario c2 \
  --episodes 300 --out results/generalisation/sumo-choose-scale-300.json
echo "== rc=$? end $(date -u +%FT%T)"

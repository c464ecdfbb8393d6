#!/bin/sh
# Issue 60, target 3 with state novelty as curiosity (docs/notes/novelty_probe.md, "State novelty as curiosity"): each
# default policy's novelty reference set, its mean and τ bounds measured on 50 drives of each training scenario, then
# its generalisation table at 60 episodes a ground, 30 for the gate row (the UGV's too: exploratory, not its
# committed 300 / 300). Usage: run-novelty.sh [SIM ...] (default: all four)
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=${PY:-.venv/bin/python}
SETS="--set gate.curiosity_signal=novelty --set gate.curiosity_reference=fitted"
TIME="/usr/bin/time -f %e_s_wall_%U_s_user_%M_kB_peak"
stamp() { echo "== $(date -u +%FT%TZ) $*"; }
seen_of() {
  case $1 in
    ugv) echo 1,2,sims/ugv/scenarios/clutter.yaml,sims/ugv/scenarios/movers.yaml ;;
    highway) echo train ;;
    pedestrian) echo crossing,rare ;;
    sumo) echo c1,c2 ;;
  esac
}
for sim in ${@:-pedestrian highway sumo ugv}; do
  seen=$(seen_of $sim)
  run=runs/$sim-novelty
  stamp "$sim: refit-bounds on $seen (the novelty reference set)"
  [ -e $run/checkpoint.pt ] || $TIME $PY -m app.cli gate refit-bounds policies/$sim-default --scenario $seen $SETS \
      --episodes 50 --out $run
  stamp "$sim: generalisation table"
  $TIME $PY -m studies.generalisation --sim $sim --run $run --episodes 60 --gate-episodes 30 --seen $seen \
      --cache results/generalisation/$sim-novelty.json --out results/generalisation/scratch-novelty-$sim.md
done
stamp done

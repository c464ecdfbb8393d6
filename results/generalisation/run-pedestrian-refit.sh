#!/bin/sh
# Issue 60, pedestrian fear AUROC (docs/notes/pedestrian_refit.md): the default's world model refitted as its README's
# step 2 did, on its training scenarios (ARM=control) or with pedestrian-shift:train beside them (ARM=shift), then the
# seen/unseen table at 300 + 300 (seen ground fixed to crossing,rare for both arms). Usage: run-pedestrian-refit.sh ARM SEED
set -e
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY=${PY:-.venv/bin/python}
ARM=$1
SEED=$2
case $ARM in
  control) SCEN=crossing,rare ;;
  shift) SCEN=pedestrian-shift:train,crossing,rare ;;
  *) echo "ARM is control or shift" >&2; exit 2 ;;
esac
RUN=runs/ped-refit-$ARM-s$SEED
TIME="/usr/bin/time -f %e_s_wall_%U_s_user_%M_kB_peak"
echo "== $(date -u +%FT%TZ) refit $ARM seed $SEED on $SCEN (at $(git rev-parse --short HEAD))"
[ -e $RUN/checkpoint.pt ] || $TIME $PY -m app.cli train --sim pedestrian --scenario $SCEN \
    --init policies/pedestrian-default --world-model-only --episodes 600 --seed $SEED --demo-episodes 30 \
    --checkpoint-every 0 --checkpoint-dtype float16 --quiet --out $RUN
$TIME $PY -m studies.generalisation --sim pedestrian --run $RUN --seen crossing,rare --episodes 300 \
    --gate-episodes 300 --cache results/generalisation/ped-refit-$ARM-s$SEED.json \
    --out results/generalisation/scratch-ped-refit-$ARM-s$SEED.md
echo "== $(date -u +%FT%TZ) done $ARM seed $SEED"

#!/bin/bash
# The five-seed route-shift study at 30,000 environment steps (docs/notes/route_shift_budget.md); resumable on any
# machine: finished trials are kept in results/route-shift-30k/trials/ (committed), and rerunning this command runs
# only the ones missing. SAGE and SAC first (the issue's comparison); rerun without --methods to add FNI-RL.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/../.."
METHODS=${METHODS---methods sage,sac}  # METHODS="" runs every method of the study
echo "== study start $(date -u +%FT%T) at $(git rev-parse --short HEAD) $METHODS"
nice -n 10 .venv/bin/python -m app.cli study route-shift --budget small --train-steps 30000 --max-concurrent 1 \
  --cpus 1 $METHODS --out results/route-shift-30k --results-doc docs/results.md --section route-shift-30k
echo "== study rc=$? end $(date -u +%FT%T)"

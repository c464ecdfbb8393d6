#!/bin/bash
# The five-seed route-shift study at 30,000 environment steps (docs/notes/route_shift_budget.md); resumable:
# rerunning this command resumes the sweep in results/route-shift-30k/sweep.
set -u
export OMP_NUM_THREADS=1
echo "== study start $(date -u +%FT%T)"
/work/main/.venv/bin/python -m app.cli study route-shift --budget small --train-steps 30000 --max-concurrent 1 --cpus 1 \
  --out results/route-shift-30k --results-doc docs/results.md --section route-shift-30k
echo "== study rc=$? end $(date -u +%FT%T)"

#!/bin/bash
# The cycles study (UGV 3, sage + frozen, five seeds, small budget) from the defaults of 2026-11-29's eighth session:
# the UGV default's disagreement curiosity and the fine-tuning anchor (finetune.anchor_relabel, prior_distill 0.5).
# Resumable: finished trials are kept in results/cycles-small-defaults/trials/; rerun this command to resume.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== study start $(date -u +%FT%T) at $(git rev-parse --short HEAD)"
nice -n 5 .venv/bin/python -m app.cli study cycles --budget small --out results/cycles-small-defaults --cpus 1 \
  --max-concurrent 1 --results-doc docs/results.md --section cycles-defaults
echo "== study rc=$? end $(date -u +%FT%T)"

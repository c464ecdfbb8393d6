#!/bin/bash
# Issues 62 (item 6: "the UGV table with adaptation from the default policy") and 63 ("each small-budget study
# <= 30 min wall on this machine"), twelfth session (2026-11-29): the UGV study rerun at the present code. Its table
# (section `ugv`) was made at 74fc8e1 (2026-11-23, 56.4 min wall, device not recorded), before the default's gate took
# the mover model, the 10-step imagined contact and the disagreement curiosity, before fine-tuning adapted as SAGE
# whatever the base, and before the compiled gate and the cheaper SAGE-SAC update. Every method, five seeds, the
# small budget, both cores (2 trials at once, as at 74fc8e1). Nothing is chosen from it: the table is reported as
# measured, with its wall time against issue 63's 30 minutes. Resumable (rerun the script: finished trials are kept).
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== ugv start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study ugv --budget small --cpus 2 --max-concurrent 2 \
  --out results/ugv-small-twelfth --section ugv --results-doc docs/results.md
echo "== rc=$? end $(date -u +%FT%T); load $(cut -d' ' -f1-3 /proc/loadavg)"

#!/bin/bash
# Issue 62, twenty-eighth session (2026-12-01, written 11:50 UTC, after the takeover anatomy and before any run of
# this). The anatomy (results/cycles-twentyeighth-takeover-anatomy.md): at the last cycle's takeover onsets the
# versions propose the expert's action in 4% (coaching every step, C1) and 23% (the defaults) of onsets, and under C1's
# gates the scripted expert's own drives fire on 6.7% of steps against 21% for the versions' drives: the versions'
# own choices at the crossing prompt the gate, and driving as the expert does would meet takeover <= 10% there.
# A probe of the last versions' critics at those onsets (docs/notes/forgetting_anatomy/omega_probe.py): value-weighted
# imitation's omega averages 0.45 at C1's onsets (67% under 0.5; 0.95 over all its labelled rows) and 0.78 at the
# defaults' (62% under 0.5): the critic discounts the expert's label where the gate fires. One lever, omega = 1
# (learner.advantage_clip=0: plain imitation of every label, eq:qa_weight switched off), two arms side by side:
#   W1: the defaults (takeovers only) with omega = 1, against this session's control (cycles-small-anatomy-control:
#       alone 0.82, takeover 0.089, static 0.86, unseen 0.70, collision cycles 4);
#   CW1: C1 (coaching every step) with omega = 1, against this session's C1 (cycles-small-anatomy-c1: alone 0.84,
#       takeover 0.147, static 0.67, unseen 0.92, collision cycles 3).
# Rule (written now): per arm, primary alone_success_last mean >= 0.90 with at most one seed lower than its reference
#   seed; guards takeover_last mean <= 0.10, static_success_last >= reference - 0.05, unseen_success_last >= reference
#   - 0.10, collision_cycles_above_first summed <= reference's. Mechanism (reported, decides nothing): onset agreement
#   by results/takeover_anatomy.py against the reference's.
#   W1 passes primary and guards: it goes to UGV 4 and ugv-fields:test:1 (the twenty-seventh session's readings for
#   C1-more) before any default changes. CW1 passes both: docs/dashboard.md's coaching sentence names omega = 1.
#   Otherwise reported; nothing changes. Not finished by 13:00 UTC: the finished seeds, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== omega-one start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc docs/results.md --out results/cycles-small-omega-one --section cycles-omega-one \
  --set learner.advantage_clip=0 > results/cycles-twentyeighth-omega-one-w1.log 2>&1 &
.venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc /tmp/omega-results.md --out results/cycles-small-coach-all-omega-one --section cycles-coach-all-omega-one \
  --set study.coach_share=1.0 --set learner.advantage_clip=0 > results/cycles-twentyeighth-omega-one-cw1.log 2>&1 &
wait
echo "== runs end $(date -u +%FT%T)"
.venv/bin/python results/takeover_anatomy.py results/cycles-small-omega-one results/cycles-small-coach-all-omega-one \
  --out results/cycles-twentyeighth-omega-one-anatomy.md
echo "== rc=$? end $(date -u +%FT%T)"

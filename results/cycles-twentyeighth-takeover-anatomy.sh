#!/bin/bash
# Issue 62, twenty-eighth session (2026-12-01, written 11:31 UTC, before any run of it): why does coaching every step
# (arm C1, results/cycles-small-coach-all) drive the crossing alone at 0.90 yet ask for help on 15% of the last
# cycle's steps, twice the defaults' 7%? The twenty-seventh session named a likely cause and did not test it: a policy
# that imitates a privileged expert drives where the gate, which cannot see the movers' paths, fears more. If so, the
# takeover target is the gate's to meet, not the rounds'.
# Both arms are driven again here (their runs/ and sessions were not kept across machines), on this host, by the same
# commands as results/cycles-twentyseventh-{control,coach-all} and into scratch folders; each should reproduce its
# committed row (control alone 0.72, takeover 0.070; C1 0.90, 0.149) if the host kind is the same.
# Then results/takeover_anatomy.py reads, per arm, over the five seeds' last cycle (v of cycle 9):
#   (a) onset agreement: at each takeover onset (the gate fired, the agent had been driving), whether the policy's own
#       proposal a_rl lies within 0.25 of the expert's action on every action component (actions in [-1, 1]);
#   (b) the gate's firing share, monitoring without taking over, of the last version's gate on (i) the version driving
#       alone and (ii) the scripted expert driving, 20 episodes of UGV 3 each from seed 9,100,000 (not the study's seeds).
# Reading (written now):
#   - "the gate fires on expert-like driving" if C1's onset agreement >= 0.6 AND its gate fires on the scripted
#     expert's own drives on >= 10% of steps (the issue's takeover target): then no policy that drives as the expert
#     does can meet takeover <= 10% under that gate, and the takeover target on UGV 3 is the gate's (issue 60's work);
#   - "the policy's own choices prompt the gate" if C1's onset agreement < 0.4 OR the expert's firing share < 5%;
#   - otherwise undecided; reported either way, nothing changes in the product.
#   Not finished by 13:30 UTC: what was measured, no verdict.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
echo "== anatomy start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
.venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc /tmp/anatomy-results.md --out results/cycles-small-anatomy-control --section anatomy-control \
  > results/cycles-twentyeighth-anatomy-control.log 2>&1 &
.venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
  --results-doc /tmp/anatomy-results.md --out results/cycles-small-anatomy-c1 --section anatomy-c1 \
  --set study.coach_share=1.0 > results/cycles-twentyeighth-anatomy-c1.log 2>&1 &
wait
echo "== runs end $(date -u +%FT%T)"
.venv/bin/python results/takeover_anatomy.py results/cycles-small-anatomy-control results/cycles-small-anatomy-c1 \
  --out results/cycles-twentyeighth-takeover-anatomy.md
echo "== rc=$? end $(date -u +%FT%T)"

#!/usr/bin/env bash
# Issue 60, twenty-fourth session, last: the warm pool of sumo-varied.sh's first launch (a pilot; rule written 01:25
# UTC, before any run of it). That launch's five refits were warm from policies/sumo-default (25 members each, so
# 125 merged, runs/sumo-varied-125/); it was stopped before any result as not the plan's 25-member candidate. The
# fresh-fit ablation then put the plan's candidate's lower unseen ranking (0.936 against 0.964) on the fresh fits, not
# the variation, which leaves the warm pool as the variation's fair test.
# Stage P (pilot): fear's unseen ranking only (no gate rows), the pool and the committed default on the same first 100
# episodes of sumo-shift:test.
# Rule: the pool goes on to sumo-varied.sh's full rule (choose-scale on c1, c2; 300 + 300; the built-in rows) only if
# its AUROC for a violation within 1 s there is at least 0.01 above the committed default's; otherwise it stops here,
# reported as a pilot that did not rank unseen danger better. A 125-member gate costs about five times the committed
# gate's step (not a deployment concern at SUMO's 0.5 s step; said if it goes on).
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
export OMP_NUM_THREADS=1
out=results/generalisation
log=$out/sumo-varied-warm.log
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): stage P, unseen ranking on the first 100 episodes"
  $PY -m studies.generalisation --sim sumo --run runs/sumo-varied-125/sumo-varied-merged --episodes 100 \
      --gate-episodes 0 --grounds unseen --out $out/sumo-varied-warm-p.md --cache $out/sumo-varied-warm-p.json &
  $PY -m studies.generalisation --sim sumo --episodes 100 --gate-episodes 0 --grounds unseen \
      --out $out/sumo-committed-100.md --cache $out/sumo-committed-100.json &
  wait
  grep -h "^| unseen" $out/sumo-varied-warm-p.md $out/sumo-committed-100.md
  echo "== $(date -u +%H:%M:%S): done P"
} 2>&1 | tee -a "$log"

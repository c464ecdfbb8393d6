#!/bin/bash
# Issue 62, twenty-seventh session (2026-12-01, written 08:14 UTC, after arm I on UGV 3 and before any run of this):
# arm I on unseen two-mover layouts (issue 62's "the same on unseen two-mover layouts"). On UGV 3 IBRL did not meet
# the rule (alone 0.82, takeover 0.129) but moved the transfer to unseen UGV 4 (0.72 against 0.58); whether it carries
# the rounds further on procedural two-mover ground is what this asks, as arm E asked it of the expert. Both arms adapt
# on ugv-fields:test:1 and are judged alone, each cycle, on ten unseen test fields with two or more movers
# (study.unseen_scenario=ugv-fields:test:2+, a field per alone seed), sage only, five seeds, this code and host (an AMD
# EPYC; the eighteenth session's control was an Intel host's, so the control runs again here beside the arm):
#   Fctl: the defaults;   Fibrl: --set learner.ibrl=true (nothing else changed; as arm I).
# Rule (arm E's primary, written before the run, committed with this script before any of its output exists):
#   Primary: Fibrl's unseen_success_last mean >= Fctl's + 0.10 with at most one seed lower than its Fctl seed: IBRL
#     carries the rounds further on unseen two-mover fields; reported as such, no default changes (arm I failed its
#     own rule on UGV 3).
#   Reported beside, not gating: alone on test:1, takeover first / last, static, supervised collision cycles.
#   Otherwise: not shown; reported. Not finished by 09:15 UTC: the seeds that finished, undecided.
set -u
export OMP_NUM_THREADS=1
cd "$(dirname "$0")/.."
arm=${1:?control or ibrl}
run() {
  echo "== $1 start $(date -u +%FT%T) at $(git rev-parse --short HEAD); load $(cut -d' ' -f1-3 /proc/loadavg)"
  shift
  .venv/bin/python -m app.cli study cycles --budget small --cpus 1 --max-concurrent 1 --methods sage \
    --results-doc docs/results.md --set study.scenario=ugv-fields:test:1 --set study.unseen_scenario=ugv-fields:test:2+ "$@"
  echo "== rc=$? end $(date -u +%FT%T)"
}
case $arm in
  control) run Fctl --out results/cycles-small-fields-unseen2-27 --section cycles-fields-unseen2-27 ;;
  ibrl) run Fibrl --out results/cycles-small-fields-unseen2-ibrl --section cycles-fields-unseen2-ibrl \
    --set learner.ibrl=true ;;
esac

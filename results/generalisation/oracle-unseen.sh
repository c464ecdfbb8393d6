#!/usr/bin/env bash
# Issue 60, nineteenth session (2026-11-30): privileged gates (true time to contact, true gap) on the unseen splits
# that miss the gate target on takeover (highway-shift:test, ugv-fields:test:2+). The rule that reads the rows is in
# docs/notes/generalisation.md ("Nineteenth session"), written before this run.
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
log=results/generalisation/oracle-unseen.log
{
  echo "== $(date -u +%H:%M:%S) at $(git rev-parse --short HEAD): highway-shift:test and ugv-fields:test:2+"
  $PY -m experiments.oracle_gate --sim highway --scenario highway-shift:test --episodes 300 --cpus 2
  $PY -m experiments.oracle_gate --sim ugv --scenario ugv-fields:test:2+ --episodes 300 --cpus 2
  echo "== $(date -u +%H:%M:%S): done"
} 2>&1 | tee -a "$log"

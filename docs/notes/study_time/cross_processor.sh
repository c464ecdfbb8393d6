#!/bin/bash
# Fifteenth session (2026-11-30): can a study's rows be made the same on an AVX-512 Intel Xeon as on the AMD EPYC hosts
# (torch there: CPU capability AVX2, as far as the AMD rows can say) by choosing the float kernels? Two settings, one
# trial each (the small UGV study's SAC, seed 0: `trial_row.py sac 0`), side by side, one core each:
#   A, as the study runs here (torch's capability AVX512, MKL's own dispatch);
#   B, ATEN_CPU_CAPABILITY=avx2 (torch's own kernels) with MKL_CBWR=AVX2 and MKL_ENABLE_INSTRUCTIONS=AVX2 (MKL's GEMM).
# Rule, written before the run: A must equal this host's study row (results/ugv-small-fifteenth, sac seed 0) in every
# scenario's success and collision, else nothing is read (the trial is not the study's). B equal to the AMD row
# (results/ugv-small-thirteenth-after, sac seed 0) in every scenario's success and collision and its continuous
# measures within 1e-6: the settings reproduce AMD's rows here, and what they cost is measured before anything is
# changed (the SAGE trial, seed 0, then checked the same way); B differs: these settings do not make rows
# processor-independent, reported, nothing changed.
set -u
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1
method=${1:-sac}
(env .venv/bin/python docs/notes/study_time/trial_row.py "$method" 0 > "/tmp/xproc-A-$method.json") &
(env ATEN_CPU_CAPABILITY=avx2 MKL_CBWR=AVX2 MKL_ENABLE_INSTRUCTIONS=AVX2 \
  .venv/bin/python docs/notes/study_time/trial_row.py "$method" 0 > "/tmp/xproc-B-$method.json") &
wait
.venv/bin/python - "$method" <<'PY'
import csv, json, sys
method = sys.argv[1]
def rows(folder):
    return {r["scenario"]: r for r in csv.DictReader(open(f"results/{folder}/seeds.csv")) if r["method"] == method and r["seed"] == "0"}
intel, amd = rows("ugv-small-fifteenth"), rows("ugv-small-thirteenth-after")
for arm in "AB":
    got = json.load(open(f"/tmp/xproc-{arm}-{method}.json"))
    print(arm, got.pop("_seconds"), "s")
    for name, ref in (("this host's study", intel), ("AMD", amd)):
        diffs = []
        for sc, r in ref.items():
            for key, value in r.items():
                if key in ("scenario", "method", "seed"):
                    continue
                mine = got.get(f"{sc}/{key}")
                if mine is None or abs(float(mine) - float(value)) > 1e-6:
                    diffs.append(f"{sc}/{key} {mine} vs {value}")
        print(f"  against {name}: {'EQUAL' if not diffs else str(len(diffs)) + ' differ: ' + '; '.join(diffs[:6])}")
PY

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
# Measured (03:49-03:50 UTC at b1cb3cc, cross_processor_sac.log): A equal to this host's study row; B differs from
# both (22 of 23 measures from AMD's): torch's and MKL's kernels are not all that differs.
# Extension C, written after B was seen, before its run (the last one: if C differs too, the question is left):
# B's settings plus numpy's own dispatch held to the AMD hosts' level (NPY_DISABLE_CPU_FEATURES for its AVX-512
# targets; numpy 2.4 here dispatches X86_V3, X86_V4, AVX512_ICL, AVX512_SPR) and numba compiling for an AVX2
# processor (NUMBA_CPU_NAME=haswell). Same reading as B's.
set -u
cd "$(dirname "$0")/../../.."
export OMP_NUM_THREADS=1
method=${1:-sac}
if [ "${2:-}" != C ]; then
  (env .venv/bin/python docs/notes/study_time/trial_row.py "$method" 0 > "/tmp/xproc-A-$method.json") &
  (env ATEN_CPU_CAPABILITY=avx2 MKL_CBWR=AVX2 MKL_ENABLE_INSTRUCTIONS=AVX2 \
    .venv/bin/python docs/notes/study_time/trial_row.py "$method" 0 > "/tmp/xproc-B-$method.json") &
fi
if [ "${2:-}" = C ]; then
  (env ATEN_CPU_CAPABILITY=avx2 MKL_CBWR=AVX2 MKL_ENABLE_INSTRUCTIONS=AVX2 \
    NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR" NUMBA_CPU_NAME=haswell NUMBA_CACHE_DIR=/tmp/numba-haswell \
    .venv/bin/python docs/notes/study_time/trial_row.py "$method" 0 > "/tmp/xproc-C-$method.json") &
fi
wait
.venv/bin/python - "$method" "${2:-}" <<'PY'
import csv, json, sys
method = sys.argv[1]
def rows(folder):
    return {r["scenario"]: r for r in csv.DictReader(open(f"results/{folder}/seeds.csv")) if r["method"] == method and r["seed"] == "0"}
intel, amd = rows("ugv-small-fifteenth"), rows("ugv-small-thirteenth-after")
for arm in "AB" + ("C" if sys.argv[2:] == ["C"] else ""):
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

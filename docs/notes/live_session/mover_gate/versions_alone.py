"""Every published version of live sessions alone on UGV 3 and 4 (exploratory; the reports' seeds).

Run from the repository root after the sessions (their versions folders under runs/ still there):
    PYTHONPATH=$PWD OMP_NUM_THREADS=1 nice -n 5 python docs/notes/live_session/mover_gate/versions_alone.py \
        OUT.json [REPORTS_FOLDER [SEED ...]]
(default: docs/notes/live_session/mover_gate, seeds 0 1 2). Versions already driven alone by the session reports
(v0, the final, the newest) are read from them, not rerun."""

import json
import sys
from pathlib import Path

import torch

from experiments.live_session import SessionPlan, alone_outcomes

torch.set_num_threads(1)
out = {}
folder = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("docs/notes/live_session/mover_gate")
for seed in [int(a) for a in sys.argv[3:]] or [0, 1, 2]:
    report = json.loads((folder / f"s{seed}" / "report.json").read_text())
    root = Path(report["versions_root"])
    done = {
        s: {"v0": report["alone"][s]["v0"], report["in_control"]: report["alone"][s]["final"]} for s in report["alone"]
    }
    if "latest" in report["alone"]["3"]:
        for s in report["alone"]:
            done[s][report["latest_published"]] = report["alone"][s]["latest"]
    plan = SessionPlan(seed=seed)
    rows = []
    for v in report["versions"]:
        n = v["number"]
        row = {
            "version": n,
            "promoted": v["promoted"],
            "supervised_collisions": v["supervised_collisions"],
            "supervised_takeover": v["supervised_takeover"],
            "updates": v["updates"],
        }
        for s in ("3", "4"):
            key = "v0" if n == 0 else n
            res = done[s].get(key) or alone_outcomes(plan, root / f"v{n:04d}", s)
            row[f"alone_{s}"] = sum(res["success"])
            row[f"alone_{s}_collisions"] = sum(res["collision"])
        rows.append(row)
        print(seed, row, flush=True)
    out[seed] = rows
Path(sys.argv[1]).write_text(json.dumps(out, indent=2) + "\n")

"""One trial of the small UGV study (its small-budget settings, 20 evaluation episodes of each of scenarios 1-4), its
row printed as JSON: ``python docs/notes/study_time/trial_row.py METHOD SEED`` (``cross_processor.sh`` compares it
with a study's seeds.csv)."""

import json
import sys
import tempfile
import time

import studies.ugv as ugv

method, seed = sys.argv[1], int(sys.argv[2])
start = time.time()
with tempfile.TemporaryDirectory() as runs:
    config = {"method": method, "seed": seed, "scenarios": ["1", "2", "3", "4"], "train_steps": 6000}
    row = ugv.trial({**config, "runs_dir": runs, "eval_episodes": 20})
row["_seconds"] = round(time.time() - start, 1)
print(json.dumps(row))

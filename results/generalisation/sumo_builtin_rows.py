"""The built-in gate rows of a SUMO run (docs/calibration.md's: gate + scripted expert, 300 episodes a scenario, the
evaluation seeds, a violation judged over 1 s), into a JSON file: ``python sumo_builtin_rows.py RUN OUT.json``. Kept
for ``sumo-contact.sh``; it is :mod:`builtin_rows` on SUMO (the same scenarios and 1 s, its table beside the JSON)."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

if __name__ == "__main__":
    sys.argv = [sys.argv[0], "sumo", *sys.argv[1:]]
    runpy.run_path(str(Path(__file__).with_name("builtin_rows.py")), run_name="__main__")

"""One trial of the small UGV study, timed: ``PYTHONPATH=$TREE python time_trial.py METHOD SEED EPISODES`` run from a
worktree of the commit to time (``git worktree add TREE COMMIT``; PYTHONPATH makes the tree's code the one imported),
one thread (``OMP_NUM_THREADS=1``), nothing else running. Prints the wall and CPU seconds of ``studies.ugv.trial`` with
the study's small-budget settings (6,000 environment steps, EPISODES evaluation episodes of each of scenarios 1-4) and
two of its success rates, so that two commits' runs can be checked to have run the same trial."""

import sys
import tempfile
import time

import core
import studies.ugv as ugv

method, seed, episodes = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
print("code from", core.__file__, file=sys.stderr)
wall, cpu = time.time(), time.process_time()
with tempfile.TemporaryDirectory() as runs:
    config = {"method": method, "seed": seed, "scenarios": ["1", "2", "3", "4"], "train_steps": 6000}
    row = ugv.trial({**config, "runs_dir": runs, "eval_episodes": episodes})
print(
    f"{method} seed {seed}: wall {time.time() - wall:.1f}s cpu {time.process_time() - cpu:.1f}s "
    f"s1 {row.get('1/success_rate_pct')} s4 {row.get('4/success_rate_pct')}"
)

"""Fixtures shared by the whole suite."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# One intra-op thread per test process (and the processes its tests start): pytest-xdist runs a worker per core, and
# torch's default of a thread per core in each of them oversubscribes the cores; under load a learning test then ran
# ten times as long (a highway study trial: 24 s with one thread, over 600 s with two beside a running study).
os.environ.setdefault("OMP_NUM_THREADS", "1")
if "torch" in sys.modules:  # imported before this file (a plugin): the variable came too late for it
    sys.modules["torch"].set_num_threads(1)

NUMBA_KERNELS = {
    # numba's on-disk cache (cache=True) beside each source, in its __pycache__: a fresh clone has none
    "gate": (
        ["core/sage/compiled_gate.py", "core/_ego_kernel.py"],
        "from core.agents import warm_gate_kernels; warm_gate_kernels(['policies/ugv-default'])",
    ),
    "teb": (
        ["sims/ugv/_teb_kernel.py"],
        "import sims; from sims.ugv.teb import TebPlanner; TebPlanner(sims.make('ugv', scenario='1'))",
    ),
}
"""The compiled kernels that many tests (and the worker processes they start) call, and a command that compiles
each group into numba's cache."""


def _cached(source: Path) -> bool:
    """numba's cache index for ``source`` exists and is newer than it (numba checks the source's stamp itself)."""
    stamp = source.stat().st_mtime
    return any(p.stat().st_mtime >= stamp for p in (source.parent / "__pycache__").glob(f"{source.stem}.*.nbi"))


def pytest_sessionstart(session: pytest.Session) -> None:
    """Under pytest-xdist, the controller fills numba's cache once, two groups of kernels side by side, before its
    workers start: otherwise, on a fresh clone, each worker (and each process a test starts before a cache file is
    written) compiles the same kernels again, tens of seconds each on the two-core machine. Does nothing without
    ``-n`` or where the cache is already newer than the kernels' sources; a failure here leaves the compiling to the
    tests, as before."""
    config = session.config
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    todo = [code for sources, code in NUMBA_KERNELS.values() if not all(_cached(ROOT / s) for s in sources)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    env.setdefault("OMP_NUM_THREADS", "1")
    runs = [
        subprocess.Popen(
            [sys.executable, "-c", code], cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        for code in todo
    ]
    for run in runs:
        try:
            run.wait(timeout=600)
        except subprocess.TimeoutExpired:
            run.kill()


@pytest.fixture(scope="module")
def ray_local() -> Iterator[None]:
    """A local two-core Ray for the tests of one module (sweeps, studies), started as the studies start it, shut down
    after them."""
    ray = pytest.importorskip("ray")
    from studies.sweep import ensure_ray

    ensure_ray(cpus=2)
    yield
    ray.shutdown()

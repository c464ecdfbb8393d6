"""The compiled contact test (``core._ego_kernel.contact``) as git holds it at a commit against now, in one process.

    .venv/bin/python -m bench.bench_ego_kernel --before REV [--batch 256,1024] [--rounds 9] [--calls 200]

On the kind of batch ``bench/bench_sac.py`` updates on (uniform random states of the UGV's 58 channels, uniform
actions, 5 members' predicted changes ~ N(0, 0.05), the UGV's contact floors) with the UGV's ego step
(``sims.ugv.env.ego_motion_layout``): the kernel at REV, imported from a copy of its file (numba caches it beside the
copy), and now take turns call by call, each call timed alone on this process's CPU clock; per round the now/before
time. It first checks that both give the same touching array and the same scan, bit for bit.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def kernel_at(rev: str, folder: Path) -> ModuleType:
    """``core/_ego_kernel.py`` at ``rev``, imported from a file in ``folder`` (numba's cache needs a file)."""
    source = subprocess.run(
        ["git", "show", f"{rev}:core/_ego_kernel.py"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    path = folder / f"ego_kernel_{rev}.py"
    path.write_text(source, encoding="utf-8")
    spec = importlib.util.spec_from_file_location(f"ego_kernel_{rev}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", required=True, metavar="REV")
    parser.add_argument("--batch", default="256,1024")
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--calls", type=int, default=200)
    args = parser.parse_args()
    from core import _ego_kernel as now
    from core.device import processor_name
    from core.motion import EgoScanStep, _kernel_geometry
    from core.sage.config import WorldModelConfig
    from sims.ugv.descriptor import contact_floors
    from sims.ugv.env import ego_motion_layout

    obs_dim, act_dim, members = 58, 2, 5
    step = EgoScanStep.of(WorldModelConfig(**ego_motion_layout()), obs_dim, act_dim)
    assert step is not None
    geometry = _kernel_geometry(step)
    floors = np.asarray(contact_floors(), dtype=np.float32)
    allowed = np.ones((1, len(floors)), dtype=np.bool_)
    batches = [int(b) for b in args.batch.split(",")]
    print(f"processor: {processor_name()}; core/_ego_kernel.py contact at {args.before} (before) and now")
    with tempfile.TemporaryDirectory() as folder:
        before = kernel_at(args.before, Path(folder))
        for batch in batches:
            rng = np.random.default_rng(batch)
            states = rng.random((batch, obs_dim)).astype(np.float32)
            actions = rng.uniform(-1, 1, (batch, act_dim)).astype(np.float32)
            delta = rng.normal(0.0, 0.05, (members, batch, len(floors))).astype(np.float32)
            outputs = {}
            for name, module in (("before", before), ("now", now)):
                touching = np.empty((members, batch), dtype=np.bool_)
                module.contact(states, actions, delta, floors, allowed, touching, *geometry)
                scan = np.empty_like(states)
                module.scan(states, actions, scan, *geometry)
                outputs[name] = (touching, scan)
            same = np.array_equal(outputs["before"][0], outputs["now"][0]) and (
                outputs["before"][1].tobytes() == outputs["now"][1].tobytes()
            )
            share = float(outputs["now"][0].mean())
            print(f"  batch {batch}: same touching and scan bits: {same}; members in contact: {share:.2f}")
            inputs = (states, actions, delta, floors, allowed, np.empty((members, batch), dtype=np.bool_), *geometry)
            calls = {
                name: (lambda m=module, a=inputs: m.contact(*a)) for name, module in (("before", before), ("now", now))
            }
            for fn in calls.values():
                for _ in range(20):
                    fn()
            ratios = []
            for r in range(args.rounds):
                spent = dict.fromkeys(calls, 0.0)
                for _ in range(args.calls):
                    for name, fn in calls.items():
                        start = time.process_time()
                        fn()
                        spent[name] += time.process_time() - start
                ms = {name: 1000.0 * s / args.calls for name, s in spent.items()}
                ratios.append(ms["now"] / ms["before"])
                print(
                    f"  batch {batch} round {r + 1}: before {ms['before']:.3f} ms  now {ms['now']:.3f} ms  "
                    f"now/before {ratios[-1]:.3f}"
                )
            under = sum(x < 1.0 for x in ratios)
            print(
                f"  batch {batch}: now/before median {statistics.median(ratios):.3f}, range {min(ratios):.3f}-"
                f"{max(ratios):.3f}, {under} of {args.rounds} rounds under 1"
            )


if __name__ == "__main__":
    main()

"""Merge the world models of several refits of one policy into one ensemble (``sage gate merge``).

A world-model-only refit (``sage train --world-model-only``) is one draw: the same command with another seed
gives a model whose warnings come earlier on one layout and later on another, enough to move the gate's safety
by several times its own sampling error (`docs/notes/calibration_history.md`, "The gate's safety over refits of the
world model"). Bagging
averages that draw out: refit K times with different seeds, then merge the K world models into one ensemble
of all their members (:func:`core.sage.world_model.merge_ensembles`) and set its κ and τ bounds on the union
of the states the refits calibrated on (each run folder's ``calibration.npz``).

The policy is the first run's; every run must hold the same acting weights (refits of one policy keep them),
because fear imagines the policy's own actions and the merged bounds are measured under it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from core.agents import FINAL_CHECKPOINT, load_agent, load_checkpoint, resolve_checkpoint, save_with_world_model
from core.sage.calibration import CALIBRATION_FILE, CalibrationSample
from core.sage.world_model import merge_ensembles

MERGE_FILE = "merge.json"
"""What a merged folder was made from (runs, members, calibration states, bounds)."""


@dataclasses.dataclass(frozen=True)
class MergeResult:
    """What :func:`merge_runs` wrote."""

    out: Path
    members: int
    runs: list[str]
    calibration_states: int
    familiar_states: int
    tau_bounds: tuple[float, float]


def _run_folder(run: str | Path) -> Path:
    path = Path(run)
    return path.parent if path.is_file() else path


def merge_runs(runs: Sequence[str | Path], out: str | Path, seed: int = 0, dtype: str = "float32") -> MergeResult:
    """Write ``out`` (a run folder: ``checkpoint.pt``, ``config.json``, ``calibration.npz``, ``merge.json``) with
    the first run's policy and all the runs' world-model members in one ensemble, calibrated on up to
    ``gate.calibration_states`` distinct states of the runs' calibration samples (drawn with ``seed``; a run without
    one, such as a committed policy's folder, adds its members and no states, and at least one run must have one).
    Models with and without the approach input merge into one that reads it (:func:`merge_ensembles`).
    A ValueError names the run that does not fit."""
    if len(runs) < 2:
        raise ValueError(f"merge needs at least two runs, got {len(runs)}")
    if dtype not in ("float32", "float16"):
        raise ValueError(f"checkpoint dtype must be float32 or float16, got {dtype!r}")
    out = Path(out)
    if (out / FINAL_CHECKPOINT).exists():
        raise ValueError(f"{out} already holds a checkpoint; choose another out folder")
    files = [resolve_checkpoint(run) for run in runs]
    if len({f.resolve() for f in files}) < len(files):
        raise ValueError("a run is given twice: merging a model with itself only repeats its members")
    payloads = [load_checkpoint(f) for f in files]
    agents = [load_agent(f) for f in files]
    first, first_payload = agents[0], payloads[0]
    if first.world_model is None:
        raise ValueError(f"{files[0]} holds no world model")
    acting = first.learner.acting_module
    for file, agent, payload in zip(files[1:], agents[1:], payloads[1:], strict=True):
        if agent.world_model is None:
            raise ValueError(f"{file} holds no world model")
        if payload["meta"]["sim"] != first_payload["meta"]["sim"]:
            raise ValueError(
                f"{file} is a {payload['meta']['sim']} run, {files[0]} a {first_payload['meta']['sim']} one"
            )
        if payload["agent_config"]["method"] != first_payload["agent_config"]["method"]:
            raise ValueError(f"{file} was trained by {payload['agent_config']['method']}, {files[0]} by another method")
        if not _same_tensors(payload["state"].get(acting), first_payload["state"].get(acting)):
            raise ValueError(
                f"{file}'s policy ({acting}) differs from {files[0]}'s: merge only world-model refits of one policy "
                "(sage train --world-model-only --init POLICY)"
            )
        differing = _gate_differences(payload["agent_config"]["gate"], first_payload["agent_config"]["gate"])
        if differing:
            raise ValueError(f"{file}'s gate config differs from {files[0]}'s in {', '.join(differing)}")
    merged = merge_ensembles([agent.world_model for agent in agents])  # type: ignore[misc]
    # a committed policy's folder keeps no sample: the union is the states of the runs that kept one
    samples, calibrated_on = [], []
    for file in files:
        path = file.parent / CALIBRATION_FILE
        if path.is_file():
            samples.append(CalibrationSample.load(path))
            calibrated_on.append(str(file.parent))
    if not samples:
        raise ValueError(
            f"none of the runs has a {CALIBRATION_FILE} to calibrate the merged ensemble on (run folders written "
            "before the calibration sample was kept: run a refit's command again)"
        )
    sample = CalibrationSample.concat(samples)
    gate_cfg = first.gate_config()
    wanted = gate_cfg.calibration_states
    rng = np.random.default_rng(seed)
    index = np.arange(len(sample)) if len(sample) <= wanted else np.sort(rng.choice(len(sample), wanted, replace=False))
    used = sample.subset(index)
    used.calibrate(merged, first.learner.rollout_policy, gate_cfg)
    merged.requires_grad_(False)
    bounds = (float(merged.tau_bounds[0]), float(merged.tau_bounds[1]))
    if not all(np.isfinite(bounds)):
        raise ValueError(
            f"the calibration samples hold {int(used.familiar.sum())} familiar states, too few to set the τ bounds"
        )
    agent_config = json.loads(json.dumps(first_payload["agent_config"]))
    agent_config["world_model_config"]["members"] = merged.members
    # a model without the approach input was widened to read it (merge_ensembles): the union reads it
    agent_config["world_model_config"]["approach_start"] = merged.cfg.approach_start
    agent_config["world_model_config"]["approach_stop"] = merged.cfg.approach_stop
    names = [str(_run_folder(run)) for run in runs]
    save_with_world_model(first_payload, out, merged, agent_config, {"merged_from": names}, dtype)
    used.save(out / CALIBRATION_FILE)
    result = MergeResult(
        out=out,
        members=merged.members,
        runs=names,
        calibration_states=len(used),
        familiar_states=int(used.familiar.sum()),
        tau_bounds=bounds,
    )
    record = {
        **dataclasses.asdict(result),
        "out": str(out),
        "seed": seed,
        "samples": [len(s) for s in samples],
        "calibrated_on": calibrated_on,
    }
    (out / MERGE_FILE).write_text(json.dumps(record, indent=2) + "\n")
    return result


def _gate_differences(gate: dict[str, Any], other: dict[str, Any]) -> list[str]:
    """The gate settings in which two saved gate configs differ, leaving out the contact floors where neither gate
    reads them (no imagined contact: a run made after its simulator declared floors saves them, an older one not)."""
    names = set(gate) | set(other)
    if not gate.get("imagined_contact") and not other.get("imagined_contact"):
        names.discard("contact_floors")
    return sorted(name for name in names if gate.get(name) != other.get(name))


def _same_tensors(a: Any, b: Any) -> bool:
    if isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor):
        return a.shape == b.shape and bool(torch.equal(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same_tensors(a[k], b[k]) for k in a)
    return False

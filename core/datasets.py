"""Offline data for learners: recorded sessions and Minari datasets as the loop's step records.

``--dataset SOURCE`` (``TrainSpec.datasets``) loads transitions into a learner's buffer before it pretrains, beside
or instead of ``--demo-episodes``. A source is either

- a recorded session file, ``<sessions folder>/<session id>.sqlite`` (:class:`core.sessions.SessionStore`): the
  steps as they were recorded, takeovers and the expert's (or person's) actions included; or
- a Minari dataset, ``minari:<dataset id>`` (``MINARI_DATASETS_PATH`` or ``~/.minari``), e.g. one written by
  ``sage export --minari``. Where its ``infos`` carry ``expert_acted`` (our exports do), those steps are the
  expert's; a dataset without that field is taken as demonstrations throughout.

Steps an expert drove become intervention samples (Ξ = 1, the executed action as the expert's label): what the
imitation terms, HG-DAgger and the diffusion policies learn from.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from core.protocol import StepRecord

MINARI_PREFIX = "minari:"


class DatasetError(ValueError):
    """A dataset source that cannot be read: the message says which and why."""


def records(source: str, obs_dim: int | None = None, act_dim: int | None = None) -> Iterator[StepRecord]:
    """The transitions of ``source`` in order, as :class:`StepRecord` (episode ends: ``done``).

    ``obs_dim``/``act_dim``: refuse a dataset of other sizes with a clear error."""
    if source.startswith(MINARI_PREFIX):
        episodes = _minari_episodes(source[len(MINARI_PREFIX) :])
    else:
        episodes = _session_episodes(Path(source))
    count = 0
    for episode in episodes:
        obs, next_obs, action = episode["obs"], episode["next_obs"], episode["action"]
        if obs_dim is not None and obs.shape[1] != obs_dim:
            raise DatasetError(f"{source}: observations have {obs.shape[1]} values, this simulator has {obs_dim}")
        if act_dim is not None and action.shape[1] != act_dim:
            raise DatasetError(f"{source}: actions have {action.shape[1]} values, this simulator has {act_dim}")
        for t in range(len(obs)):
            expert = bool(episode["expert"][t])
            executed = action[t].astype(np.float32)
            last = t == len(obs) - 1
            yield StepRecord(
                episode=int(episode["id"]),
                t=t,
                obs=obs[t].astype(np.float32),
                a_rl=episode["a_rl"][t].astype(np.float32),
                a_expert=executed if expert else None,
                action=executed,
                takeover=expert,
                gate_fired=False,
                actor="expert" if expert else "agent",
                fear=math.nan,
                threshold=math.nan,
                curiosity=math.nan,
                reward=float(episode["reward"][t]),
                cost=float(episode["cost"][t]),
                violation=bool(episode["violation"][t]),
                terminated=bool(episode["terminated"][t]),
                truncated=bool(episode["truncated"][t]) or (last and not bool(episode["terminated"][t])),
                next_obs=next_obs[t].astype(np.float32),
                wall_time=0.0,
                info={"conflict": bool(episode["conflict"][t])},
            )
            count += 1
    if count == 0:
        raise DatasetError(f"{source}: no transitions")


def _session_episodes(path: Path) -> Iterator[dict[str, Any]]:
    from core.sessions import SessionError, SessionStore

    if path.suffix != ".sqlite" or not path.is_file():
        raise DatasetError(
            f"dataset {str(path)!r}: give a recorded session file (<sessions folder>/<id>.sqlite) or minari:<id>"
        )
    try:
        arrays = SessionStore(path.parent).steps(path.stem)
    except (SessionError, OSError, ValueError) as exc:
        raise DatasetError(f"dataset {path}: {exc}") from None
    for episode in np.unique(arrays["episode"]):
        idx = np.flatnonzero(arrays["episode"] == episode)
        idx = idx[np.argsort(arrays["t"][idx])]
        yield {
            "id": int(episode),
            "obs": arrays["obs"][idx],
            "next_obs": arrays["next_obs"][idx],
            "action": arrays["action"][idx],
            "a_rl": np.nan_to_num(arrays["a_rl"][idx]),
            "expert": arrays["actor"][idx] != "agent",
            "reward": arrays["reward"][idx],
            "cost": np.nan_to_num(arrays["cost"][idx]),
            "violation": arrays["violation"][idx],
            "conflict": arrays["conflict"][idx],
            "terminated": arrays["terminated"][idx],
            "truncated": arrays["truncated"][idx],
        }


def _minari_episodes(dataset_id: str) -> Iterator[dict[str, Any]]:
    import minari

    try:
        dataset = minari.load_dataset(dataset_id)
    except Exception as exc:  # minari raises FileNotFoundError, ValueError, ... by version
        raise DatasetError(f"minari:{dataset_id}: {exc}") from None
    for episode in dataset.iterate_episodes():
        observations = np.asarray(episode.observations, np.float32)
        actions = np.asarray(episode.actions, np.float32)
        if actions.ndim == 1:
            actions = actions[:, None]
        steps = len(actions)
        infos = episode.infos if isinstance(episode.infos, dict) else {}

        def info(name: str, fill: float, steps: int = steps, infos: dict[str, Any] = infos) -> np.ndarray:
            if name not in infos:
                return np.full(steps, fill)
            values = np.asarray(infos[name])
            return values.reshape(len(values), -1)[1 : steps + 1, 0]  # infos[0] is reset's

        expert = info("expert_acted", 1.0).astype(bool)  # a plain dataset: demonstrations throughout
        a_rl = np.asarray(infos["a_rl"], np.float32)[1 : steps + 1] if "a_rl" in infos else actions
        yield {
            "id": int(episode.id),
            "obs": observations[:steps],
            "next_obs": observations[1 : steps + 1],
            "action": actions,
            "a_rl": np.nan_to_num(a_rl.reshape(steps, -1)),
            "expert": expert,
            "reward": np.asarray(episode.rewards, np.float64),
            "cost": np.nan_to_num(info("cost", 0.0)),
            "violation": info("violation", 0.0).astype(bool),
            "conflict": info("conflict", 0.0).astype(bool),
            "terminated": np.asarray(episode.terminations, bool),
            "truncated": np.asarray(episode.truncations, bool),
        }

"""Export a recorded session as a Minari dataset, so that offline-RL tools can learn from it.

Per episode: ``observations`` (T+1: every step's observation and the last next-observation), the
``actions`` actually executed (T), ``rewards``, ``terminations``, ``truncations``. SAGE's own signals go
to ``infos``, following Minari's convention that ``infos[0]`` belongs to ``reset`` and ``infos[i+1]`` to
step ``i``: ``takeover`` (bool), ``expert_acted`` (bool: a person or script produced the action),
``a_rl`` (the policy's proposal), ``a_expert`` (NaN where no expert acted), ``fear``, ``curiosity``,
``threshold`` (NaN where the gate computed none), ``cost``, ``violation`` and ``conflict`` (the simulator's
near-miss flag, a label the world model may learn). Scalars are stored with a
trailing axis of 1, (T+1, 1), which Minari's arrow storage needs to read them back.

An episode still open when the session stopped (a crash, or the server shut down mid-episode) is
exported with its last step marked truncated, so nothing recorded is lost.
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from core.sessions import SessionStore

_DATASET_ID = re.compile(r"^[A-Za-z0-9_.\-]+(/[A-Za-z0-9_.\-]+){0,2}$")


def dataset_id_for(name: str) -> str:
    """``name`` as a Minari dataset id: ``[namespace/][env/]name-vN`` (``-v0`` added when absent)."""
    if not _DATASET_ID.match(name):
        raise ValueError(
            f"invalid Minari dataset name {name!r}: use letters, digits, '_', '.', '-', "
            "at most two '/' (namespace/env/name), e.g. sage/ugv/takeovers"
        )
    return name if re.search(r"-v\d+$", name) else f"{name}-v0"


def _column(values: np.ndarray, fill: float | bool) -> np.ndarray:
    """Prepend the reset row and give scalars a trailing axis, as Minari's arrow storage wants."""
    values = np.asarray(values)
    if values.ndim == 1:
        values = values[:, None]
    head = np.full((1, values.shape[1]), fill, dtype=values.dtype)
    return np.concatenate([head, values], axis=0)


def episode_buffers(store: SessionStore, session_id: str) -> list[Any]:
    """The session's episodes as Minari ``EpisodeBuffer`` objects (empty episodes skipped)."""
    from minari.data_collector.episode_buffer import EpisodeBuffer

    arrays = store.steps(session_id)
    buffers: list[Any] = []
    for episode in np.unique(arrays["episode"]):
        idx = np.flatnonzero(arrays["episode"] == episode)
        idx = idx[np.argsort(arrays["t"][idx])]
        if idx.size == 0:
            continue
        obs = arrays["obs"][idx]
        observations = np.concatenate([obs, arrays["next_obs"][idx[-1:]]], axis=0)
        terminations = arrays["terminated"][idx].copy()
        truncations = arrays["truncated"][idx].copy()
        if not (terminations[-1] or truncations[-1]):
            truncations[-1] = True
        actor = arrays["actor"][idx]
        infos = {
            "takeover": _column(arrays["takeover"][idx], False),
            "expert_acted": _column(actor != "agent", False),
            "a_rl": _column(arrays["a_rl"][idx], np.nan),
            "a_expert": _column(arrays["a_expert"][idx], np.nan),
            "fear": _column(arrays["fear"][idx], np.nan),
            "curiosity": _column(arrays["curiosity"][idx], np.nan),
            "threshold": _column(arrays["threshold"][idx], np.nan),
            "cost": _column(arrays["cost"][idx], 0.0),
            "violation": _column(arrays["violation"][idx], False),
            "conflict": _column(arrays["conflict"][idx] > 0, False),
        }
        buffers.append(
            EpisodeBuffer(
                id=int(episode),
                observations=observations.astype(np.float32),
                actions=arrays["action"][idx].astype(np.float32),
                rewards=arrays["reward"][idx].astype(np.float64).tolist(),
                terminations=terminations.tolist(),
                truncations=truncations.tolist(),
                infos=infos,
            )
        )
    return buffers


def export_minari(
    store: SessionStore,
    session_id: str,
    name: str,
    *,
    observation_space: gym.spaces.Space[Any] | None = None,
    action_space: gym.spaces.Space[Any] | None = None,
    datasets_root: str | Path | None = None,
) -> Any:
    """Write ``session_id`` as the Minari dataset ``name`` and return the ``MinariDataset``.

    Spaces default to unbounded boxes of the recorded widths (pass the simulator's own spaces when it
    can be built). ``datasets_root`` overrides ``MINARI_DATASETS_PATH`` for this call.
    """
    import minari

    dataset_id = dataset_id_for(name)
    info = store.info(session_id)
    buffers = episode_buffers(store, session_id)
    if not buffers:
        raise ValueError(f"session {session_id!r} has no recorded steps to export")
    obs_dim = buffers[0].observations.shape[1]
    act_dim = buffers[0].actions.shape[1]
    observation_space = observation_space or gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)
    action_space = action_space or gym.spaces.Box(-np.inf, np.inf, (act_dim,), np.float32)
    previous = os.environ.get("MINARI_DATASETS_PATH")
    if datasets_root is not None:
        os.environ["MINARI_DATASETS_PATH"] = str(Path(datasets_root).resolve())
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # minari nags about author/permalink fields
            return minari.create_dataset_from_buffers(
                dataset_id,
                buffers,
                observation_space=observation_space,
                action_space=action_space,
                algorithm_name=f"SAGE session ({info.expert_mode or 'unknown'} expert)",
                author="sage",
                description=(
                    f"SAGE session {session_id} on {info.sim} scenario {info.scenario}, policy {info.policy}. "
                    "infos: takeover, expert_acted, a_rl, a_expert, fear, curiosity, threshold, cost, violation, "
                    "conflict "
                    "(infos[0] is the reset row; infos[i+1] belongs to step i)."
                ),
                data_format="arrow",
            )
    finally:
        if datasets_root is not None:
            if previous is None:
                os.environ.pop("MINARI_DATASETS_PATH", None)
            else:
                os.environ["MINARI_DATASETS_PATH"] = previous

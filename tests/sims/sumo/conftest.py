"""Shared helpers for the SUMO tests. libsumo runs one simulation per process: every env made here is closed."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest
import torch

from sims.sumo import SumoEnv


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)


@pytest.fixture
def make_env() -> Iterator[Callable[..., SumoEnv]]:
    """Build in-process envs; all of them are closed at the end of the test, pass or fail."""
    made: list[SumoEnv] = []

    def factory(**kwargs: Any) -> SumoEnv:
        env = SumoEnv(**kwargs)
        made.append(env)
        return env

    yield factory
    for env in made:
        env.close()

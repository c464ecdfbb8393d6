"""Fixtures shared by the whole suite."""

from __future__ import annotations

from collections.abc import Iterator

import pytest


@pytest.fixture(scope="module")
def ray_local() -> Iterator[None]:
    """A local two-core Ray for the tests of one module (sweeps, studies), started as the studies start it, shut down
    after them."""
    ray = pytest.importorskip("ray")
    from studies.sweep import ensure_ray

    ensure_ray(cpus=2)
    yield
    ray.shutdown()

"""Simulators whose evaluation is a study protocol of its own, not episodes per scenario.

``sage eval`` (one run or several) asks :func:`protocol_for` first; a simulator without an entry is evaluated
the common way (:func:`core.train.evaluate`, episodes per scenario). Highway is evaluated as the paper does:
one episode per logged scenario of a split, in the normal and the adversarial mode (:mod:`studies.highway`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

RunsTable = Callable[[Sequence[str], int, str, str, Sequence[int], bool], tuple[str, list[dict[str, Any]]]]
"""``(runs, episodes, split, mode, seeds, progress) -> (table text, episode rows)``."""


def _highway(*args: Any) -> tuple[str, list[dict[str, Any]]]:
    from studies.highway import runs_table

    return runs_table(*args)


PROTOCOLS: dict[str, RunsTable] = {"highway": _highway}


def protocol_for(sim: str) -> RunsTable | None:
    return PROTOCOLS.get(sim)

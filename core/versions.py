"""Numbered policy versions in one folder, written atomically: what fine-tuning publishes and the loop takes.

``<run>/versions/vNNNN/`` holds ``checkpoint.pt`` (the checkpoint format of :mod:`core.agents`, loadable with
``load_agent(folder)``) and ``metrics.json`` (the round's losses and data). ``v0000`` is the deployed starting
policy. A version folder appears in one ``os.replace`` of a fully written temporary folder, so a reader never sees
a half-written version, and a crash mid-write leaves only a ``.tmp-*`` folder that listing ignores and the next
writer removes. Which version a round continues from (never a rejected one): :func:`line_head`.
"""

from __future__ import annotations

import json
import math
import os
import re
import secrets
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from core.agents import AgentMeta, load_checkpoint, resolve_checkpoint, save_checkpoint
from core.promotion import is_promoted, read_verdict
from core.sage.learner import BaseLearner

VERSION_DIR = re.compile(r"^v(\d{4,})$")
CHECKPOINT_FILE = "checkpoint.pt"
METRICS_FILE = "metrics.json"
TMP_PREFIX = ".tmp-"


class FinetuneError(RuntimeError):
    """A fine-tuning set-up that cannot work (no such version, a policy of other dimensions, ...)."""


@dataclass(frozen=True)
class Version:
    number: int
    path: Path
    """The version folder (what :func:`core.agents.load_agent` takes)."""
    metrics: dict[str, Any]

    @property
    def name(self) -> str:
        return version_name(self.number)

    @property
    def parent(self) -> int | None:
        parent = self.metrics.get("parent")
        return int(parent) if isinstance(parent, int) else None

    def summary(self) -> dict[str, Any]:
        """The JSON-ready line the dashboard lists."""
        m = self.metrics
        return {
            "number": self.number,
            "name": self.name,
            "parent": self.parent,
            "created": m.get("created"),
            "updates": m.get("updates", 0),
            "skipped": m.get("skipped", 0),
            "episodes": m.get("episodes_total", 0),
            "takeover_samples": m.get("takeover_samples", 0),
            "losses": m.get("losses", {}),
            "promotion": self.verdict(),
        }

    def verdict(self) -> dict[str, Any] | None:
        """Whether this version may drive (:mod:`core.promotion`): ``promoted``, ``reason``, ``evaluation``."""
        if self.number == 0:
            return read_verdict(self.path) or {"promoted": True, "reason": "the policy deployed by the operator"}
        return read_verdict(self.path)

    @property
    def promoted(self) -> bool:
        return is_promoted(self.path, self.number)


def version_name(number: int) -> str:
    return f"v{number:04d}"


def _write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(f"{TMP_PREFIX}{path.name}.{secrets.token_hex(3)}")
    tmp.write_text(json.dumps(data, indent=2, default=_json_default) + "\n")
    os.replace(tmp, path)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return str(value)


class VersionStore:
    """The numbered policy versions of one fine-tuning run (see the module docstring for the layout)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def versions(self) -> list[Version]:
        """Every complete version, oldest first. Temporary folders and unreadable metrics are skipped."""
        if not self.root.is_dir():
            return []
        found: list[Version] = []
        for child in self.root.iterdir():
            match = VERSION_DIR.match(child.name)
            if not match or not child.is_dir() or not (child / CHECKPOINT_FILE).is_file():
                continue
            try:
                metrics = json.loads((child / METRICS_FILE).read_text())
            except (OSError, ValueError):
                metrics = {}
            found.append(Version(int(match.group(1)), child, metrics if isinstance(metrics, dict) else {}))
        return sorted(found, key=lambda v: v.number)

    def latest(self) -> Version | None:
        versions = self.versions()
        return versions[-1] if versions else None

    def get(self, number: int) -> Version:
        for version in self.versions():
            if version.number == number:
                return version
        known = ", ".join(v.name for v in self.versions()) or "none"
        raise FinetuneError(f"no version {version_name(number)} in {self.root} (there are: {known})")

    def clean(self) -> int:
        """Remove the temporary folders a crashed writer left behind; returns how many."""
        if not self.root.is_dir():
            return 0
        removed = 0
        for child in self.root.iterdir():
            if child.name.startswith(TMP_PREFIX):
                shutil.rmtree(child, ignore_errors=True) if child.is_dir() else child.unlink(missing_ok=True)
                removed += 1
        return removed

    def ensure_initial(self, policy: str | Path) -> Version:
        """``v0000``: the deployed starting policy (its checkpoint copied in), unless versions exist already."""
        latest = self.latest()
        if latest is not None:
            return latest
        source = resolve_checkpoint(policy)
        load_checkpoint(source)  # refuse anything that is not a readable SAGE checkpoint before publishing it
        metrics = {"version": 0, "parent": None, "created": time.time(), "source": str(source), "updates": 0}
        return self._publish(0, lambda folder: shutil.copyfile(source, folder / CHECKPOINT_FILE), metrics)

    def publish(
        self,
        learner: BaseLearner,
        meta: AgentMeta,
        metrics: dict[str, Any],
        extra_state: dict[str, Any] | None = None,
    ) -> Version:
        """Write the learner as the next version (atomically: all of it appears at once, or nothing); ``extra_state``:
        entries added to the checkpoint's state beside the learner's (e.g. :data:`core.familiar.STATE_KEY`)."""
        latest = self.latest()
        number = 0 if latest is None else latest.number + 1
        metrics = {**metrics, "version": number, "created": time.time()}

        def write(folder: Path) -> Path:
            return save_checkpoint(folder / CHECKPOINT_FILE, learner, meta, extra_state=extra_state)

        return self._publish(number, write, metrics)

    def _publish(self, number: int, write: Callable[[Path], Any], metrics: dict[str, Any]) -> Version:
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = self.root / f"{TMP_PREFIX}{version_name(number)}-{os.getpid()}-{secrets.token_hex(3)}"
        tmp.mkdir()
        try:
            write(tmp)
            _write_json_atomic(tmp / METRICS_FILE, metrics)
            final = self.root / version_name(number)
            os.replace(tmp, final)  # a directory rename: the version appears complete or not at all
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return Version(number, final, metrics)


def rejected(version: Version) -> bool:
    """Whether ``version`` was judged unfit to drive: its evaluation did not promote it, or it was rolled back
    live (:mod:`core.promotion`). A version never judged (a ``sage cycles`` run evaluates none) is not rejected."""
    if version.number == 0:
        return False
    verdict = read_verdict(version.path)
    if not verdict:  # never judged (no file, an unreadable or an empty one)
        return False
    return not verdict.get("promoted") or bool(verdict.get("rolled_back"))


def line_head(versions: VersionStore) -> Version | None:
    """The version a round continues: the newest one not rejected (the version in control, or a newer one not
    judged yet), so that a rejected version is never the start of another."""
    for version in reversed(versions.versions()):
        if not rejected(version):
            return version
    return None

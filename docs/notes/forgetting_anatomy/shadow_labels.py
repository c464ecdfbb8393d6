"""SAGE's rounds given DAgger's coverage (issue 62, seventeenth session; a diagnosis, not a method).

The observability probe (docs/notes/observability_probe.md) found that a student of the default actor's shape drives
UGV 3 alone without failures once the scripted expert has labelled the states the student reaches itself, while the
cycles' versions, which have the expert's labels only where the gate handed over, plateau near 0.8. This script runs
the cycles study's own trial (`studies.cycles_study.trial`, the small budget, sage, the present defaults) with one
change: on every deployment step the agent drives, the scripted expert's action at that state is recorded as if the
expert had taken over (the agent's action is still the one executed), so the rounds imitate (ω-weighted, beside the
SAC terms and the anchor) on every state the versions reach. The takeover columns of such a run count those labels
and mean nothing; its alone and static columns are read.

    OMP_NUM_THREADS=1 python docs/notes/forgetting_anatomy/shadow_labels.py OUT SEED [SEED ...] [--plain]
        [--mode all | --mode fraction:P | --mode before:K] [--scenario NAME --unseen NAME]

Run from the repository root; OUT gets `runs/sage-sSEED` and `rows.json` (the trial's row per seed). ``--mode``
says which agent steps get the expert's label: ``all`` (the default), ``fraction:P`` (each with probability P, as a
person coaching part of the time might), ``before:K`` (the K agent steps before each takeover onset, each with the
expert's own choice at it, as a person reviewing the approach after a takeover might)."""

from __future__ import annotations

import collections
import json
import random
import sys
from pathlib import Path
from typing import Any

import numpy as np

import studies.cycles as cycles
from core.loop import NoGate, Runner
from core.protocol import StepRecord
from core.sessions import SessionWriter


class LabellingPolicy:
    """The deployed policy, asking the scripted expert for its action at the same state each time it acts."""

    def __init__(self, policy: Any, env: Any) -> None:
        self.policy, self.env, self.label = policy, env, None

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        self.label = np.asarray(self.env.unwrapped.expert_action(), np.float32)
        return self.policy.act(obs, deterministic=deterministic)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.policy, name)


class ShadowRunner(Runner):
    """A deployment runner whose agent-driven steps (those ``MODE`` picks) are recorded with the expert's label as
    takeovers."""

    mode = "all"
    """Which agent steps get the label (the module's ``--mode``); set by :func:`main`."""

    def __init__(self, env: Any, policy: Any, gate: Any, expert: Any, **kwargs: Any) -> None:
        super().__init__(env, LabellingPolicy(policy, env), gate, expert, **kwargs)
        self.labels: dict[int, np.ndarray] = {}
        self.rng = random.Random(int(kwargs.get("seed", 0)))
        self.step_listeners.insert(0, self._label)

    def set_policy_at_boundary(self, policy: Any, gate: Any = None) -> None:
        super().set_policy_at_boundary(LabellingPolicy(policy, self.env), gate)

    def _label(self, record: StepRecord) -> None:
        if record.takeover or not isinstance(self.policy, LabellingPolicy) or self.policy.label is None:
            return
        kind, _, value = self.mode.partition(":")
        if kind == "all" or (kind == "fraction" and self.rng.random() < float(value)):
            record.a_expert, record.takeover = self.policy.label, True
        elif kind == "before":
            self.labels[id(record)] = self.policy.label  # given by Delayed at the next onset, if within K steps


class Delayed:
    """The session writer's listeners, holding the last K steps back: at a takeover onset the agent steps among them
    (same episode, back to the first expert step) are labelled with the expert's own choice there before written."""

    def __init__(self, writer: Any, runner: ShadowRunner, steps: int) -> None:
        self.writer, self.runner = writer, runner
        self.pending: collections.deque[StepRecord] = collections.deque()
        self.steps = steps

    def on_step(self, record: StepRecord) -> None:
        onset = record.takeover and self.pending and not self.pending[-1].takeover
        if onset:
            for earlier in reversed(self.pending):
                label = self.runner.labels.get(id(earlier))
                if earlier.takeover or earlier.episode != record.episode or label is None:
                    break
                earlier.a_expert, earlier.takeover = label, True
            self.flush()
        self.pending.append(record)
        while len(self.pending) > self.steps:
            self.write(self.pending.popleft())

    def write(self, record: StepRecord) -> None:
        self.runner.labels.pop(id(record), None)
        self.writer.on_step(record)

    def flush(self) -> None:
        while self.pending:
            self.write(self.pending.popleft())

    def on_episode(self, summary: Any) -> None:
        self.flush()
        self.writer.on_episode(summary)


def attach(writer: Any, runner: Any) -> Any:
    """``SessionWriter.attach``, through :class:`Delayed` for a ``before:K`` shadow runner."""
    if isinstance(runner, ShadowRunner) and runner.mode.startswith("before:"):
        delayed = Delayed(writer, runner, int(runner.mode.partition(":")[2]))
        runner.step_listeners.append(delayed.on_step)
        runner.episode_listeners.append(delayed.on_episode)
        return writer
    return ORIGINAL_ATTACH(writer, runner)


ORIGINAL_ATTACH = SessionWriter.attach


def runner(env: Any, policy: Any, gate: Any, expert: Any, **kwargs: Any) -> Runner:
    """Deployment (a gate) gets the shadow labels; the alone evaluations (no gate) run as the study runs them."""
    if isinstance(gate, NoGate):
        return Runner(env, policy, gate, expert, **kwargs)
    return ShadowRunner(env, policy, gate, expert, **kwargs)


def main(
    out: Path, seeds: list[int], shadow: bool = True, mode: str = "all", scenario: str = "3", unseen: str = ""
) -> None:
    """``shadow=False`` runs the trial as the study does (the check that this in-process call reproduces it)."""
    from studies.cycles_study import trial

    if shadow:
        ShadowRunner.mode = mode
        cycles.Runner = runner  # type: ignore[assignment,misc]
        SessionWriter.attach = attach  # type: ignore[method-assign]
    rows_file = out / "rows.json"
    rows = json.loads(rows_file.read_text()) if rows_file.is_file() else {}
    for seed in seeds:
        config = {
            "method": "sage",
            "seed": seed,
            "sim": "ugv",
            "scenario": scenario,
            "unseen_scenario": unseen,
            "policy": str(Path("policies/ugv-default").resolve()),
            "train_steps": 6000,
            "eval_episodes": 10,
            "runs_dir": str(out / "runs"),
            "finetune": [],
            "promotion": False,
            "static_scenarios": "",
        }
        rows[str(seed)] = trial(config)
        print(seed, rows[str(seed)], flush=True)
        out.mkdir(parents=True, exist_ok=True)
        rows_file.write_text(json.dumps(rows, indent=1, sort_keys=True))


if __name__ == "__main__":
    plain = "--plain" in sys.argv
    args = [a for a in sys.argv[1:] if a != "--plain"]
    options = {"--mode": "all", "--scenario": "3", "--unseen": ""}
    for flag in options:
        if flag in args:
            at = args.index(flag)
            options[flag] = args[at + 1]
            del args[at : at + 2]
    main(
        Path(args[0]),
        [int(s) for s in args[1:]],
        shadow=not plain,
        mode=options["--mode"],
        scenario=options["--scenario"],
        unseen=options["--unseen"],
    )

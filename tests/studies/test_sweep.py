"""The Ray sweep: one process per (method, seed), rows back, resumable, failures named."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("ray")

from studies.sweep import LedgerError, SweepError, TrialLedger, _trial_row, run_sweep, run_tasks


def toy_trial(config: dict[str, Any]) -> dict[str, float]:
    """A trial whose result depends on method and seed, and which reports its process id."""
    offset = {"a": 0.0, "b": 100.0}[config["method"]]
    if config.get("fail_seed") == config["seed"] and config["method"] == "b":
        raise RuntimeError("deliberate failure")
    return {
        "score": offset + config["seed"] * config["scale"],
        "worker_pid": float(os.getpid()),
        "niceness": float(os.nice(0)),  # the calling thread's, which is the one running the trial
    }


def toy_task(value: int, folder: str) -> tuple[int, int]:
    """A task that leaves a file behind (work a failed sibling must not lose) and says which process ran it."""
    if value < 0:
        raise RuntimeError("deliberate failure")
    Path(folder, f"done-{value}").write_text(str(os.getpid()))
    return value * 10, os.getpid()


def test_sweep_runs_every_method_and_seed_in_worker_processes(ray_local: None, tmp_path: Path) -> None:
    rows = run_sweep(toy_trial, ["a", "b"], [1, 3], tmp_path, "toy", settings={"scale": 2.0})
    assert [(r["method"], r["seed"]) for r in rows] == [("a", 1), ("a", 3), ("b", 1), ("b", 3)]
    assert [r["score"] for r in rows] == [2.0, 6.0, 102.0, 106.0]
    assert all(int(r["worker_pid"]) != os.getpid() for r in rows)  # trials ran outside the driver
    # at the driver's priority: Ray's default would lower them by 15, starving a study beside any other job
    assert all(r["niceness"] == os.nice(0) for r in rows)
    # a second call with the same folder resumes the finished experiment instead of rerunning it
    again = run_sweep(toy_trial, ["a", "b"], [1, 3], tmp_path, "toy", settings={"scale": 2.0})
    assert [r["worker_pid"] for r in again] == [r["worker_pid"] for r in rows]


@pytest.mark.slow  # two more Ray worker starts (~20 s on the shared machine); the run path is covered above
def test_failed_trials_are_named_and_others_kept(ray_local: None, tmp_path: Path) -> None:
    with pytest.raises(SweepError, match="b seed 2"):
        run_sweep(toy_trial, ["b"], [1, 2], tmp_path, "fails", settings={"scale": 1.0, "fail_seed": 2})
    with pytest.raises(ValueError, match="duplicate"):
        run_sweep(toy_trial, ["a"], [1, 1], tmp_path, "dup")


def test_tasks_run_in_fresh_worker_processes_in_order_and_failures_are_named(ray_local: None, tmp_path: Path) -> None:
    results = run_tasks(toy_task, [{"value": v, "folder": str(tmp_path)} for v in (2, 1, 3)])
    assert [value for value, _ in results] == [20, 10, 30]
    pids = {pid for _, pid in results}
    # three tasks on two cores: a fresh process each all the same (libsumo: one simulation per process)
    assert len(pids) == 3 and os.getpid() not in pids
    with pytest.raises(SweepError, match=r"1 of 2 tasks failed.*route2: RuntimeError: deliberate failure$"):
        run_tasks(toy_task, [{"value": 4, "folder": str(tmp_path)}, {"value": -1, "folder": str(tmp_path)}],
                  labels=["route1", "route2"])  # fmt: skip
    assert (tmp_path / "done-4").is_file()  # the sibling of the failed task finished and kept its work
    with pytest.raises(ValueError, match="1 labels for 2 calls"):
        run_tasks(toy_task, [{"value": 1, "folder": "x"}] * 2, labels=["only one"])


def test_a_ledger_keeps_finished_trials_so_another_machine_runs_only_the_missing_ones(
    ray_local: None, tmp_path: Path
) -> None:
    ledger = TrialLedger.for_results(tmp_path / "results" / "trials", {"scale": 2.0}, tmp_path / "results")
    first = run_sweep(toy_trial, ["a"], [1, 3], tmp_path / "machine1", "toy", {"scale": 2.0}, ledger=ledger)
    assert sorted(p.name for p in ledger.folder.glob("*.json")) == ["a-s1.json", "a-s3.json"]
    # a fresh machine (no Tune state) asked for more: the ledger's trials are read, only b's run
    rows = run_sweep(toy_trial, ["a", "b"], [1, 3], tmp_path / "machine2", "toy", {"scale": 2.0}, ledger=ledger)
    expected = [("a", 1, 2.0), ("a", 3, 6.0), ("b", 1, 102.0), ("b", 3, 106.0)]
    assert [(r["method"], r["seed"], r["score"]) for r in rows] == expected
    # the first machine, whose Tune state holds a's trials only, asked for b too: b runs there as well (its stored
    # experiment, resumed, would never run b) and that state is kept aside
    (ledger.folder / "b-s1.json").unlink()
    (ledger.folder / "b-s3.json").unlink()
    rows = run_sweep(toy_trial, ["a", "b"], [1, 3], tmp_path / "machine1", "toy", {"scale": 2.0}, ledger=ledger)
    assert [(r["method"], r["seed"], r["score"]) for r in rows] == expected
    assert [p.name.split(".")[0] for p in (tmp_path / "machine1").glob("toy.before-*")] == ["toy"]
    assert [r["worker_pid"] for r in rows[:2]] == [r["worker_pid"] for r in first]  # not run again
    assert all(r["trial_seconds"] > 0 for r in rows)
    assert len(list(ledger.folder.glob("*.json"))) == 4


def test_a_ledger_refuses_rows_run_with_other_settings_and_reads_paths_portably(tmp_path: Path) -> None:
    root = tmp_path / "results"
    ledger = TrialLedger.for_results(root / "trials", {"scale": 2.0, "runs_dir": str(root / "runs")}, root)
    assert ledger.settings["runs_dir"] == "<results>/runs"  # the same on any machine
    asked = TrialLedger.for_results(root / "trials", {"scale": 2.0, "methods": ["a"]}, root)
    assert "methods" not in asked.settings  # which methods one invocation runs does not change a trial
    ledger.write({"method": "a", "seed": 0, "trial_seconds": 1.0, "score": 5.0})
    moved = tmp_path / "elsewhere"
    same = TrialLedger.for_results(root / "trials", {"scale": 2.0, "runs_dir": str(moved / "runs")}, moved)
    assert same.read(["a"], [0, 1]) == {("a", 0): {"method": "a", "seed": 0, "trial_seconds": 1.0, "score": 5.0}}
    other = TrialLedger.for_results(root / "trials", {"scale": 3.0, "runs_dir": str(root / "runs")}, root)
    with pytest.raises(LedgerError, match=r"a-s0.json ran with other settings \(scale\)"):
        other.read(["a"], [0])
    (root / "trials" / "a-s0.json").write_text("{not json")
    with pytest.raises(LedgerError, match="not a trial ledger row"):
        ledger.read(["a"], [0])


def test_a_trial_stopped_before_it_reported_has_no_row() -> None:
    assert _trial_row({"method": "a", "seed": 0}, {"time_total_s": 3.0, "pid": 1}) is None
    row = _trial_row({"trial": {"method": "b", "seed": 2}, "scale": 1.0}, {"time_total_s": 3.0, "score": 1.5})
    assert row == {"method": "b", "seed": 2, "trial_seconds": 3.0, "score": 1.5}

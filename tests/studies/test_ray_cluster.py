"""A study on a Ray cluster (``sage study --address``): a real head started with ``ray start`` in a temporary
folder (token authentication when ``~/.ray/auth_token`` exists, as Ray then starts it), and an address where no
cluster runs, refused in seconds with one line."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("ray")

from studies.sweep import ClusterError, check_cluster_address, ensure_ray, run_sweep

START_TIMEOUT = 120.0
"""Seconds for ``ray start --head`` to answer on its port on the shared machine before the test is skipped."""


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def tiny_trial(config: dict[str, Any]) -> dict[str, float]:
    return {"score": 10.0 * config["seed"], "worker_pid": float(os.getpid())}


@pytest.fixture(scope="module")
def ray_head() -> Iterator[str]:
    """``ray start --head --block`` in its own process group (so that only what it started is stopped: never
    ``ray stop``, which stops every Ray on the machine); yields its address. Skipped when Ray cannot start here."""
    ray_cli = Path(sys.executable).with_name("ray")
    if not ray_cli.exists():
        pytest.skip(f"no ray command beside {sys.executable}")
    port = free_port()
    auth_mode = os.environ.get("RAY_AUTH_MODE")  # ensure_ray may set it for a token cluster: put it back after
    temp = tempfile.mkdtemp(prefix="rh", dir="/tmp")  # Ray's socket paths must stay short
    log = Path(temp, "start.log")
    head = subprocess.Popen(
        [str(ray_cli), "start", "--head", "--block", f"--port={port}", "--num-cpus=1", "--include-dashboard=false",
         f"--temp-dir={temp}", "--disable-usage-stats", "--node-ip-address=127.0.0.1"],
        stdout=log.open("w"), stderr=subprocess.STDOUT, start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while True:
            try:
                check_cluster_address(f"127.0.0.1:{port}", timeout=1.0)
                break
            except ClusterError:
                if head.poll() is not None or time.monotonic() > deadline:
                    tail = " / ".join(log.read_text(errors="replace").strip().splitlines()[-3:])
                    pytest.skip(f"ray start --head did not come up here: {tail[:300]}")
                time.sleep(0.5)
        yield f"127.0.0.1:{port}"
    finally:
        import ray

        ray.shutdown()
        if head.poll() is None:
            os.killpg(head.pid, signal.SIGTERM)  # --block: the head stops the processes it started
            try:
                head.wait(5)  # it lingers ~30 s after SIGTERM: what it left is killed with the group
            except subprocess.TimeoutExpired:
                os.killpg(head.pid, signal.SIGKILL)
                head.wait(10)
        shutil.rmtree(temp, ignore_errors=True)
        if auth_mode is None:
            os.environ.pop("RAY_AUTH_MODE", None)
        else:
            os.environ["RAY_AUTH_MODE"] = auth_mode


def test_a_sweep_runs_on_a_cluster_started_with_ray_start(ray_head: str, tmp_path: Path) -> None:
    import ray

    try:
        rows = run_sweep(tiny_trial, ["a"], [1], tmp_path, "on-cluster", address=ray_head)
    finally:
        ray.shutdown()  # the next tests start without Ray
    assert [(r["method"], r["seed"], r["score"]) for r in rows] == [("a", 1, 10.0)]
    assert int(rows[0]["worker_pid"]) != os.getpid()  # the trial ran in the cluster's worker


def test_a_wrong_address_fails_in_seconds_with_one_line() -> None:
    import ray

    nobody = f"127.0.0.1:{free_port()}"  # nothing listens there
    started = time.monotonic()
    with pytest.raises(ClusterError) as refused:
        ensure_ray(nobody)
    assert time.monotonic() - started < 10
    message = str(refused.value)
    assert len(message.splitlines()) == 1 and "ray start --head" in message and nobody in message
    assert not ray.is_initialized()
    with pytest.raises(ClusterError, match="not HOST:PORT"):
        check_cluster_address("localhost")
    with socket.socket() as silent:  # a port that accepts and says nothing: ray.init would retry for minutes
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        started = time.monotonic()
        with pytest.raises(ClusterError, match="timed out"):
            check_cluster_address(f"127.0.0.1:{silent.getsockname()[1]}", timeout=1.0)
        assert time.monotonic() - started < 5


def test_sage_study_with_a_wrong_address_is_one_line_and_exit_2() -> None:
    from typer.testing import CliRunner

    from app.cli import app

    started = time.monotonic()
    result = CliRunner().invoke(app, ["study", "ugv", "--budget", "smoke", "--address", f"127.0.0.1:{free_port()}"])
    assert result.exit_code == 2, result.output
    assert len(result.output.strip().splitlines()) == 1 and "ray start --head" in result.output
    assert time.monotonic() - started < 10

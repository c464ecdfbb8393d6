"""``--device`` on the commands that train or drive a run: one line and exit 2 where the device is not there."""

from __future__ import annotations

import pytest
import torch
from typer.testing import CliRunner

from app.cli import app
from app.cli.options import checked_device

UGV_DEFAULT = "policies/ugv-default"


@pytest.mark.parametrize(
    "args",
    [
        ["train", "--episodes", "1"],
        ["study", "ugv"],
        ["gate", "evaluate", UGV_DEFAULT],
        ["gate", "choose-scale", UGV_DEFAULT, "--scenario", "1"],
        ["gate", "refit-bounds", UGV_DEFAULT, "--scenario", "1", "--out", "unused"],
    ],
)
def test_device_cuda_without_cuda_is_one_line_and_exit_2(args: list[str]) -> None:
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    result = CliRunner().invoke(app, [*args, "--device", "cuda"])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "no CUDA device" in lines[0] and "Traceback" not in result.output


def test_device_auto_is_the_cpu_here_and_a_bad_name_is_refused() -> None:
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    assert checked_device("auto") == "cpu"
    result = CliRunner().invoke(app, ["train", "--episodes", "1", "--device", "tpu"])
    assert result.exit_code == 2 and "choose one of auto, cpu, cuda" in result.output


def test_train_help_names_the_device_option() -> None:
    result = CliRunner().invoke(app, ["train", "--help"], env={"COLUMNS": "1000"})
    assert result.exit_code == 0 and "--device" in result.output

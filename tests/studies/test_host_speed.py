"""The host's reference speed (:mod:`studies.host_speed`): the real workload, at a tiny size."""

from __future__ import annotations

import math

import pytest
import torch

from studies.host_speed import main, measure_host_speed


def test_the_reference_times_both_workloads_on_one_thread_and_restores_torchs_threads() -> None:
    threads = torch.get_num_threads()
    speed = measure_host_speed(sim_steps=40, updates=3)
    assert torch.get_num_threads() == threads
    for rate in (speed.sim_steps_per_s, speed.sac_updates_per_s):
        assert math.isfinite(rate) and rate > 0
    # a step of the simulator with its expert costs far less than a SAC update at batch 256
    assert speed.sim_steps_per_s > speed.sac_updates_per_s
    assert speed.seconds > 0 and speed.processor
    assert f"{speed.sac_updates_per_s:.1f} SAC updates/s" in speed.words()
    # the float kernels decide whether a learner's rows reproduce on another host: said beside the processor
    assert speed.kernels == torch.backends.cpu.get_cpu_capability() and speed.kernels
    assert f"{speed.processor}, torch's CPU kernels {speed.kernels}): " in speed.words()


def test_the_command_refuses_an_empty_reference(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError, match="must be >= 1"):
        measure_host_speed(sim_steps=0)
    with pytest.raises(SystemExit):
        main(["--repeat", "0"])
    assert "--repeat must be >= 1" in capsys.readouterr().err

"""``bench/bench_gate.py --policy``: the gate timed as a committed policy deploys it, on recorded real steps."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench import bench_gate
from core.agents import load_agent

ROOT = Path(__file__).resolve().parents[2]
UGV = ROOT / "policies" / "ugv-default"


@pytest.fixture(scope="module")
def recording() -> list[bench_gate.Transition]:
    return bench_gate.record(load_agent(UGV), bench_gate.default_scenario("ugv"), 12)


def test_the_recording_is_the_policy_driving_with_its_gate(recording: list[bench_gate.Transition]) -> None:
    assert len(recording) == 12 and recording[0].first
    assert all(step.obs.shape == step.next_obs.shape == (58,) for step in recording)
    # no expert: the executed action is the policy's; the gate was fitted, so its fear is a number at every step
    assert all((step.a_rl == step.action).all() for step in recording)
    assert all(0.0 <= step.fear <= 1.0 for step in recording)


def test_the_timed_gates_are_the_deployed_one_and_its_torch_kernel(recording: list[bench_gate.Transition]) -> None:
    agent = load_agent(UGV)
    gates = bench_gate.policy_gates(agent)
    deployed, torch_kernel = gates[bench_gate.DEPLOYED], gates[bench_gate.TORCH_KERNEL]
    assert deployed.cfg.mover_model == "cartesian" and deployed.cfg.contact_horizon == 10
    assert deployed.cfg == agent.config.gate and torch_kernel.cfg == deployed.cfg
    fears = bench_gate.replay(agent.policy, deployed, recording)
    # the replay is the recording's loop: the same gate gives the same fear, step by step
    assert fears == pytest.approx([step.fear for step in recording], abs=1e-6)
    assert type(deployed.kernel()).__name__ == "CompiledGateKernel"
    clocks: list[list[float]] = [[], []]
    torch_fears = bench_gate.replay(agent.policy, torch_kernel, recording, clocks)
    assert type(torch_kernel.kernel()).__name__ == "GateKernel"
    assert len(clocks[0]) == len(clocks[1]) == len(recording) and min(clocks[1]) > 0
    assert torch_fears == pytest.approx(fears, abs=1e-4)


def test_the_report_is_written_into_its_block(recording: list[bench_gate.Transition], tmp_path: Path) -> None:
    from bench.bench_sac import write_block

    report, medians = bench_gate.policy_report(str(UGV), "movers", recording, 1, (0.0, 0.0, 0.0), "the command")
    assert report.startswith("`the command` at commit ")
    assert set(medians) == {bench_gate.DEPLOYED, bench_gate.TORCH_KERNEL, bench_gate.SYNTHETIC}
    assert min(medians.values()) > 0 and "Deployed / synthetic: " in report
    for part in ("mover velocities", "rollout", "movers' contact", "observe", "policy"):
        assert f"| {part} |" in report
    doc = tmp_path / "speed.md"
    doc.write_text(f"before\n{bench_gate.POLICY_START}\nold\n{bench_gate.POLICY_END}\nafter\n")
    write_block(doc, report, bench_gate.POLICY_START, bench_gate.POLICY_END)
    text = doc.read_text()
    assert "old" not in text and text.startswith("before\n") and text.endswith("after\n") and report in text


def test_the_side_by_side_workers_replay_the_saved_recording_bit_for_bit(tmp_path: Path) -> None:
    """``bench/gate_side_by_side.py``: the recording the code now makes, saved and read back by a replay worker (what
    each tree's process runs), gives the worker's gate the recorded fears exactly, and a time per step."""
    from bench import gate_side_by_side

    path = tmp_path / "recording.npz"
    scenario = gate_side_by_side.save_recording(path, str(UGV), None, 10)
    assert scenario == bench_gate.default_scenario("ugv")
    result = gate_side_by_side.replay_worker(path, str(UGV), rounds=1, core=None)
    assert result["fear_difference"] == 0.0 and result["median_ms"] > 0.0

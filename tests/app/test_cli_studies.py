"""The studies through the command line: highway closed-loop training and the paper's table, the SUMO route shift
with its figures, and another run's policy as the expert. Tiny budgets: these check the wiring, not learning."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from app.cli import app
from core.agents import load_agent
from core.experts import PolicyExpert
from core.sage.config import for_method
from core.train import RunConfig, Trainer
from studies.envs import env_factory

torch.set_num_threads(1)
TINY = ["--set", "hidden=16", "--set", "batch_size=8", "--set", "learning_starts=10", "--quiet"]
TINY_MODEL = ["--set", "wm_min_samples=20", "--set", "wm_fit_every=40", "--set", "virtual_starts=16"]


def sage(*args: str) -> Any:
    result = CliRunner().invoke(app, list(args))
    return result


def rows_of(run: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]


@pytest.fixture(scope="module")
def highway_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "hw-sac"
    result = sage(
        "train", "--sim", "highway", "--method", "sac", "--episodes", "2", "--max-episode-steps", "10",
        "--adversarial-ratio", "1", "--checkpoint-every", "0", "--out", str(out), *TINY,
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return out


def test_highway_training_is_closed_loop_adversarial(highway_run: Path) -> None:
    rows = [r for r in rows_of(highway_run) if r["phase"] == "train"]
    assert [r["adversarial"] for r in rows] == [1.0, 1.0]
    config = json.loads((highway_run / "config.json").read_text())
    assert config["run"]["scenarios"] == ["train"] and config["meta"]["sim"] == "highway"
    study = json.loads((highway_run / "study.json").read_text())
    assert study == {"protocol": "closed-loop-adversarial", "adversarial_ratio": 1.0, "predictor": "policy"}


def test_highway_eval_prints_the_paper_columns_for_both_modes(highway_run: Path, tmp_path: Path) -> None:
    save = tmp_path / "rows.jsonl"
    result = sage(
        "eval", str(highway_run), "--sim", "highway", "--split", "test", "--mode", "normal,adversarial",
        "--episodes", "2", "--seeds", "0,1", "--save", str(save), "--quiet",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    header = lines[0]
    for mode in ("normal", "adversarial"):
        for title in ("S.R.(%)", "C.R.(%)", "Speed (m/s)", "Acc. (m/s²)"):
            assert f"{mode} {title}" in header
    cells = [c.strip() for c in re.split(r"\s{2,}", lines[2])]
    assert cells[:3] == ["test", "hw-sac", "4"]  # 2 scenarios x 2 seeds in each mode
    saved = [json.loads(line) for line in save.read_text().splitlines()]
    normal = [r for r in saved if r["mode"] == "normal"]
    adversarial = [r for r in saved if r["mode"] == "adversarial"]
    assert len(normal) == len(adversarial) == 4
    for rows, first in ((normal, 3), (adversarial, 7)):
        success = 100 * np.mean([r["success"] for r in rows])
        collision = 100 * np.mean([r["collision"] for r in rows])
        speed = [r["speed_mean"] for r in rows]
        assert cells[first : first + 3] == [
            f"{success:.1f}",
            f"{collision:.1f}",
            f"{np.mean(speed):.2f} ± {np.std(speed):.2f}",
        ]
    assert "mean_gap" in result.output and "min_ttc" in result.output  # the interaction table follows


def test_highway_eval_of_named_scenarios_gives_the_per_scenario_table(highway_run: Path) -> None:
    """--scenario (or --gate / --expert) is not silently dropped for the paper's table: it runs those scenarios."""
    result = sage("eval", str(highway_run), "--scenario", "test-adversarial", "--episodes", "1", "--quiet")
    assert result.exit_code == 0, result.output
    assert "(highway test-adversarial)" in result.output and "S.R.(%)" not in result.output


def test_highway_eval_refuses_a_bad_set_or_another_simulator(highway_run: Path) -> None:
    result = sage("eval", str(highway_run), "--split", "validation", "--episodes", "1", "--quiet")
    assert result.exit_code == 2 and "choose from train, test" in result.output
    result = sage("eval", str(highway_run), "--sim", "sumo", "--episodes", "1", "--quiet")
    assert result.exit_code == 2 and "trained on highway" in result.output


def test_expert_run_becomes_a_policy_expert_for_demonstrations(highway_run: Path) -> None:
    run = RunConfig(
        sim="highway", scenarios=["train"], episodes=0, demo_episodes=1, expert=str(highway_run), max_episode_steps=6
    )
    cfg = for_method("sage", hidden=16, batch_size=8, pretrain_bc_steps=1, pretrain_critic_steps=1)
    trainer = Trainer(run, cfg, env_factory("highway"), None, False)
    try:
        assert isinstance(trainer.expert, PolicyExpert)
        trainer.demonstrate()
    finally:
        trainer.close()
    buffer, expert = trainer.learner.buffer, load_agent(highway_run).policy
    assert len(buffer) == 6 and buffer.takeover_count() == 6
    for obs, a_expert in zip(buffer.obs[:6], buffer.a_expert[:6], strict=True):
        np.testing.assert_allclose(a_expert, expert.act(obs, deterministic=True), atol=1e-6)


def test_expert_option_is_recorded_and_a_misfit_expert_is_refused(highway_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "hw-sage"
    result = sage(
        "train", "--sim", "highway", "--method", "sage", "--episodes", "1", "--max-episode-steps", "5",
        "--adversarial-ratio", "0", "--expert", str(highway_run), "--checkpoint-every", "0", "--out", str(out), *TINY,
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    config = json.loads((out / "config.json").read_text())
    assert config["run"]["expert"] == str(highway_run) and config["meta"]["extra"]["expert"] == str(highway_run)
    result = sage(
        "train", "--sim", "sumo", "--protocol", "route-shift", "--c1", "1", "--c2", "1",
        "--expert", str(highway_run), "--out", str(tmp_path / "misfit"), *TINY,
    )  # fmt: skip
    assert result.exit_code == 2
    assert "83 observations / 2 actions, this simulator has 29 / 1" in result.output
    result = sage(
        "train", "--sim", "sumo", "--protocol", "route-shift", "--c1", "1", "--c2", "1",
        "--expert-c2", str(highway_run), "--out", str(tmp_path / "misfit-c2"), *TINY,
    )  # fmt: skip
    assert result.exit_code == 2 and "--expert-c2" in result.output and "the SUMO env has 29 / 1" in result.output


@pytest.fixture(scope="module")
def route_shift_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    out = tmp_path_factory.mktemp("runs") / "rs-fni"
    result = sage(
        "train", "--sim", "sumo", "--protocol", "route-shift", "--method", "fni-rl", "--c1", "2", "--c2", "2",
        "--max-episode-steps", "25", "--checkpoint-every", "0", "--out", str(out), *TINY, *TINY_MODEL,
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return out, result


def test_route_shift_runs_c1_on_route_1_then_c2_on_route_2_with_special_vehicles(route_shift_run) -> None:
    out, _ = route_shift_run
    rows = rows_of(out)
    assert [(r["route"], r["special_vehicles"]) for r in rows] == [(1.0, 0.0), (1.0, 0.0), (2.0, 1.0), (2.0, 1.0)]
    assert all(r["takeover_rate"] == 0.0 for r in rows)  # FNI-RL: fear without takeovers
    assert np.isfinite(rows[-1]["mean_fear"]) and np.isfinite(rows[-1]["mean_curiosity"])
    study = json.loads((out / "study.json").read_text())
    assert (study["protocol"], study["c1"], study["c2"], study["method"]) == ("route-shift", 2, 2, "fni-rl")


def test_route_shift_training_writes_its_figures_and_phase_table(route_shift_run) -> None:
    out, result = route_shift_run
    for name in ("route_shift_rates.png", "route_shift_signals.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG" and (out / name).stat().st_size > 20_000
        assert f"figure: {out / name}" in result.output
    assert "FNI-RL: C1 last 1" in result.output and "FNI-RL: C2 first 1" in result.output
    # the fear term says what it ran on: a budget measured on the simulator's own fear, and λ
    assert re.search(r"fear term: budget F_0 [0-9.e-]+ \(measured at the last world-model fit\), λ ", result.output)


def test_figure_command_overlays_runs_with_labels(route_shift_run, tmp_path: Path) -> None:
    out, _ = route_shift_run
    result = sage(
        "figure", "route-shift", str(out), str(out), "--label", "a,b", "--out", str(tmp_path), "--window", "2"
    )
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "route_shift_rates.png",
        "route_shift_signals_rs-fni.png",
    ]
    assert "a: C2 last 1" in result.output and "b: C1 last 1" in result.output
    result = sage("figure", "route-shift", str(out), "--label", "a,b", "--out", str(tmp_path))
    assert result.exit_code == 2 and "2 labels for 1 runs" in result.output
    result = sage("figure", "route-shift", str(tmp_path), "--out", str(tmp_path))
    assert result.exit_code == 2 and "no metrics.jsonl" in result.output


def test_figure_command_refuses_runs_that_switch_at_different_episodes_in_one_line(tmp_path: Path) -> None:
    # a switch by steps (the study's): each run reaches route 2 after its own number of episodes
    for name, c1 in (("a", 3), ("b", 5)):
        run = tmp_path / name
        run.mkdir()
        rows = [{"steps": 10, "success": 0.0, "collision": 1.0, "red_light": 0.0, "route": 1 if i < c1 else 2}
                for i in range(c1 + 2)]  # fmt: skip
        (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    result = sage("figure", "route-shift", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(tmp_path / "fig"))
    assert result.exit_code == 2 and "switch routes after different numbers of episodes" in result.output
    assert "Traceback" not in result.output


def test_protocol_options_that_do_not_fit_fail_with_a_clear_message(tmp_path: Path) -> None:
    result = sage("train", "--sim", "highway", "--protocol", "route-shift", "--out", str(tmp_path / "x"), "--quiet")
    assert result.exit_code == 2 and "route-shift is the SUMO study" in result.output
    result = sage("train", "--sim", "sumo", "--c1", "5", "--out", str(tmp_path / "y"), "--quiet")
    assert result.exit_code == 2 and "belong to --protocol route-shift" in result.output


def test_study_settings_from_the_command_line_take_the_settings_own_types() -> None:
    from app.cli.study import setting_value

    assert setting_value(["1", "2", "3", "4"], "1, 3", "scenarios") == ["1", "3"]
    assert setting_value(20, "2", "min_eval_episodes") == 2
    assert setting_value("scripted", "hg-dagger", "expert") == "hg-dagger"
    import pytest

    with pytest.raises(ValueError, match="is a number"):
        setting_value(20, "many", "min_eval_episodes")


def test_learning_curves_are_drawn_from_run_folders(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    for method, seed, rate in (("sac", 0, 0.2), ("sac", 1, 0.4), ("sage", 0, 0.8)):
        folder = runs / f"{method}-s{seed}"
        folder.mkdir(parents=True)
        rows = [
            {"phase": "train", "steps_done": 100 * (i + 1), "success": rate, "collision": 1 - rate} for i in range(5)
        ]
        (folder / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    result = sage("figure", "learning-curves", str(runs), "--methods", "sac,sage", "--out", str(tmp_path / "fig"))
    assert result.exit_code == 0, result.output
    assert (tmp_path / "fig" / "learning_curves.png").stat().st_size > 10_000
    result = sage("figure", "learning-curves", str(runs), "--methods", "td3", "--out", str(tmp_path / "fig"))
    assert result.exit_code == 2 and "td3" in result.output

"""The studies' experts (studies/experts.py): an RL-trained expert is trained once per results folder for the
budget's expert steps and reused; every expert is measured alone and the measurement is cached."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from studies.experts import check_choice, expert_quality, expert_run, quality_cache, quality_note


def test_an_unknown_expert_is_a_clear_error_naming_the_choices() -> None:
    with pytest.raises(ValueError, match=r"expert=nope: give one of scripted, sumo, hg-dagger, .*sac.*path"):
        check_choice("nope", aliases=("sumo",))
    check_choice("sumo", aliases=("sumo",))
    check_choice("sac")
    with pytest.raises(ValueError, match="expert_steps"):
        expert_run("d3qn", Path("unused"), "pedestrian", "crossing", demo_episodes=1, expert_steps=0)


def test_the_scripted_expert_is_none_and_is_measured_alone(tmp_path: Path) -> None:
    assert expert_run("scripted", tmp_path, "pedestrian", "crossing", demo_episodes=1, expert_steps=10) is None
    cache = quality_cache(tmp_path, "scripted", None, ["crossing"])
    quality = expert_quality(None, "pedestrian", ["crossing"], 3, cache)
    # the scripted cautious driver sees the pedestrian: it never collides
    assert quality["crossing"]["collision"] == 0.0 and cache.is_file()
    assert "collision 0%" in quality_note("scripted", quality, 3)


def test_an_rl_expert_trains_once_for_the_expert_steps_and_is_reused(tmp_path: Path) -> None:
    run = expert_run("d3qn", tmp_path, "pedestrian", "crossing", demo_episodes=2, expert_steps=150)
    assert run is not None and Path(run) == (tmp_path / "experts" / "d3qn").resolve()
    config = json.loads((Path(run) / "config.json").read_text())
    assert config["meta"]["method"] == "d3qn" and config["run"]["train_steps"] == 150
    assert config["run"]["demo_episodes"] == 2 and config["meta"]["extra"]["steps_done"] == 150
    stamp = (Path(run) / "checkpoint.pt").stat().st_mtime_ns
    assert expert_run("d3qn", tmp_path, "pedestrian", "crossing", demo_episodes=2, expert_steps=150) == run
    assert (Path(run) / "checkpoint.pt").stat().st_mtime_ns == stamp  # cached, not retrained

    cache = quality_cache(tmp_path, "d3qn", None, ["crossing"])
    quality = expert_quality(run, "pedestrian", ["crossing"], 2, cache)
    assert set(quality["crossing"]) >= {"collision"} and 0.0 <= quality["crossing"]["collision"] <= 1.0
    stored = json.loads(cache.read_text())
    stored["quality"]["crossing"]["collision"] = 0.5  # a cached measurement is read back, not measured again
    cache.write_text(json.dumps(stored))
    assert expert_quality(run, "pedestrian", ["crossing"], 2, cache)["crossing"]["collision"] == 0.5
    # another episode count is another measurement
    assert expert_quality(run, "pedestrian", ["crossing"], 1, cache)["crossing"]["collision"] in (0.0, 1.0)

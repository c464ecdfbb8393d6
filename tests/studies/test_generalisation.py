"""studies.generalisation: the seen-vs-unseen table on a tiny sample, its cache and its document."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

import sims
from studies import generalisation
from studies.generalisation import generalisation_table, render, write_section

torch.set_num_threads(1)
RUN = "policies/ugv-default"


def test_the_table_measures_both_grounds_and_resumes_from_its_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    grounds = {"unseen": ["ugv-fields:test:2"], "seen": ["1", "2"]}
    cache = tmp_path / "cache.json"
    rows = generalisation_table(RUN, "ugv", grounds, episodes=2, gate_episodes=2, max_steps=12, cache=cache)
    assert [r.ground for r in rows] == ["unseen", "seen"]
    unseen, seen = rows
    assert unseen.episodes == 2 and seen.episodes == 2 and seen.scenarios == ["1", "2"]
    assert unseen.steps <= 24 and seen.steps <= 24
    assert 0 <= unseen.fire_elsewhere <= 1 and math.isfinite(unseen.tau_mean) and math.isfinite(seen.curiosity_mean)
    assert seen.gate["episodes"] == 2 and 0 <= seen.gate["takeover_rate"] <= 1

    def fail(*args: object, **kwargs: object) -> None:
        raise AssertionError("measured again although cached")

    monkeypatch.setattr(generalisation, "collect_signals", fail)
    monkeypatch.setattr(generalisation, "run_gated", fail)
    again = generalisation_table(RUN, "ugv", grounds, episodes=2, gate_episodes=2, max_steps=12, cache=cache)
    assert [r.steps for r in again] == [r.steps for r in rows]
    # a run stopped early: with cached_only, the table is made of the chunks the cache holds
    store = json.loads(cache.read_text())
    cache.write_text(json.dumps({k: v for k, v in store.items() if not k.startswith("gate|") or "|1|" in k}))
    partial = generalisation_table(
        RUN, "ugv", grounds, episodes=2, gate_episodes=2, max_steps=12, cache=cache, cached_only=True
    )
    assert [r.episodes for r in partial] == [2, 2] and partial[0].gate == {} and partial[1].gate["episodes"] == 1

    by_movers = generalisation.ugv_rows_by_movers(cache, RUN, scenario="ugv-fields:test:2", max_steps=12)
    assert sum(r.episodes for r in by_movers) == 2 and len(by_movers) == 1  # one field: one group

    out = tmp_path / "generalisation.md"
    out.write_text("# Generalisation\n\n## highway: kept\n\nother sim\n")
    section = render(
        rows,
        sim="ugv",
        run=RUN,
        horizon_s=1.0,
        command="python -m studies.generalisation",
        commit="abc",
        by_movers=by_movers,
    )
    write_section(out, "ugv", section)
    out.write_text(out.read_text() + "\n## sumo: after\n\nthird sim\n")
    write_section(out, "ugv", section)  # a second run replaces its own section, where it stood
    text = out.read_text()
    assert text.count("## ugv: ") == 1 and "## highway: kept" in text
    assert text.index("## highway: kept") < text.index("## ugv: ") < text.index("## sumo: after")
    assert text.endswith("third sim\n") and "\n\n\n" not in text
    assert "Telling a step on unseen ground from one on seen ground" in text
    scores = generalisation.novelty(unseen, seen)
    assert set(scores) == {"curiosity", "sigma", "cost", "fear"} and all(0 <= v <= 1 for v in scores.values())
    assert "| unseen | ugv-fields:test:2 | 2 (" in text and "`abc`" in text and "### The unseen ground" in text
    assert " min wall" not in text  # neither host nor wall time given: the header says neither
    stated = render(rows, sim="ugv", run=RUN, horizon_s=1.0, command="c", commit="abc", host="Xeon", wall_s=90.0)
    assert "at commit `abc` on Xeon (the CPU), 1.5 min wall for this command" in stated


def test_the_entry_point_refuses_bad_input_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert generalisation.main(["--sim", "ugv", "--episodes", "0"]) == 2
    assert generalisation.main(["--sim", "point", "--run", RUN]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "no procedural family for 'point'" in err[1]


def test_the_seen_ground_defaults_to_the_runs_training_scenarios_and_can_be_given() -> None:
    trained = generalisation.default_grounds(RUN, "ugv")
    assert trained["seen (training scenarios)"][:2] == ["1", "2"]
    given = generalisation.default_grounds(RUN, "ugv", seen=["1", "sims/ugv/scenarios/movers.yaml"])
    assert given == {
        "unseen (ugv-fields:test)": ["ugv-fields:test"],
        "seen (scenarios given)": ["1", "sims/ugv/scenarios/movers.yaml"],
    }


def test_the_entry_point_takes_seen_scenarios_as_comma_lists(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    asked: dict[str, object] = {}

    def table(run: str, sim: str, grounds: dict[str, list[str]], *args: object, **kwargs: object) -> list[object]:
        asked.update(grounds)
        return []

    monkeypatch.setattr(generalisation, "generalisation_table", table)
    argv = ["--sim", "ugv", "--episodes", "1", "--seen", "1,2", "--seen", "sims/ugv/scenarios/movers.yaml"]
    assert generalisation.main([*argv, "--grounds", "seen", "--out", str(tmp_path / "g.md")]) == 0
    assert asked == {"seen (scenarios given)": ["1", "2", "sims/ugv/scenarios/movers.yaml"]}


def test_a_fresh_block_of_seeds_draws_other_fields_and_its_rows_read_only_that_block(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    grounds = {"unseen": ["ugv-fields:test"]}
    cache = tmp_path / "cache.json"
    table = generalisation.EVAL_SEED
    fresh = generalisation.FRESH_SEED
    for first in (table, fresh):
        generalisation_table(
            RUN, "ugv", grounds, episodes=1, gate_episodes=0, max_steps=5, cache=cache, first_seed=first
        )
    keys = list(json.loads(cache.read_text()))
    assert len(keys) == 2 and any(f"|{table}|" in k for k in keys) and any(f"|{fresh}|" in k for k in keys)
    env = sims.descriptor("ugv").make("ugv-fields:test")
    try:
        drawn = []
        for first in (table, fresh):
            env.reset(seed=first)
            drawn.append(env.unwrapped.layout)
    finally:
        env.close()
    assert drawn[0] != drawn[1]  # the blocks drive other fields of the split
    both = generalisation.ugv_rows_by_movers(cache, RUN, max_steps=5)
    one = generalisation.ugv_rows_by_movers(cache, RUN, max_steps=5, seeds=range(fresh, fresh + 1))
    assert sum(r.episodes for r in both) == 2 and sum(r.episodes for r in one) == 1

    asked: dict[str, object] = {}

    def measure(*args: object, **kwargs: object) -> list[object]:
        asked.update(kwargs)
        return []

    monkeypatch.setattr(generalisation, "generalisation_table", measure)
    out = str(tmp_path / "g.md")
    assert generalisation.main(["--episodes", "1", "--grounds", "unseen", "--first-seed", "123", "--out", out]) == 0
    assert asked["first_seed"] == 123
    assert generalisation.main(["--episodes", "1", "--first-seed", "-1", "--out", out]) == 2


def test_gate_settings_over_the_runs_own_are_measured_under_their_own_cache_keys(tmp_path: Path) -> None:
    grounds = {"unseen": ["ugv-fields:test:2"]}
    cache = tmp_path / "cache.json"
    plain = generalisation_table(RUN, "ugv", grounds, episodes=1, gate_episodes=0, max_steps=30, cache=cache)
    fixed = generalisation_table(
        RUN,
        "ugv",
        grounds,
        episodes=1,
        gate_episodes=0,
        max_steps=30,
        cache=cache,
        gate_settings=generalisation.gate_settings_of(["gate.use_curiosity=false"]),
    )
    keys = list(json.loads(cache.read_text()))
    assert len(keys) == 2 and sum("|gate:use_curiosity=False|" in k for k in keys) == 1
    # without curiosity τ stays at the middle of its bounds; with it τ moves with curiosity
    assert fixed[0].steps == plain[0].steps
    signals = json.loads(cache.read_text())
    taus = next(v["tau"] for k, v in signals.items() if "use_curiosity" in k)
    moving = next(v["tau"] for k, v in signals.items() if "use_curiosity" not in k)
    assert max(taus) - min(taus) < 1e-9 < max(moving) - min(moving)


def test_the_entry_point_takes_gate_settings_only(capsys: pytest.CaptureFixture[str]) -> None:
    assert generalisation.gate_settings_of(["gate.use_curiosity=false", "gate.tau_scale=0.9"]) == {
        "use_curiosity": False,
        "tau_scale": 0.9,
    }
    # a setting that reads the contact floors brings the simulator's, as `sage gate --set` does
    floors = list(sims.descriptor("highway").contact_floors)
    assert generalisation.gate_settings_of(["gate.closing_veto=3"], "highway") == {
        "closing_veto": 3.0,
        "contact_floors": floors,
    }
    assert generalisation.gate_settings_of(["gate.closing_veto=3"]) == {"closing_veto": 3.0}
    assert generalisation.main(["--sim", "ugv", "--episodes", "1", "--set", "env.expert.yield_to_movers=false"]) == 2
    assert generalisation.main(["--sim", "ugv", "--episodes", "1", "--set", "gate.no_such_setting=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "gate settings only" in err[0] and "no_such_setting" in err[1]


def test_gate_settings_the_run_cannot_take_are_refused_in_one_line_before_any_drive(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    def drive(*args: object, **kwargs: object) -> None:
        raise AssertionError("drove before refusing the settings")

    monkeypatch.setattr(generalisation, "generalisation_table", drive)
    novelty = ["--sim", "ugv", "--episodes", "1", "--set", "gate.curiosity_signal=novelty"]
    # against a moving average: meaningless (the UGV default reads its curiosity against a fitted reference)
    assert generalisation.main([*novelty, "--set", "gate.curiosity_reference=recent"]) == 2
    # the committed policy's calibration kept no reference set of states
    assert generalisation.main([*novelty, "--set", "gate.curiosity_reference=fitted"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "curiosity_reference=fitted" in err[0] and "refit-bounds" in err[1]


def test_extra_grounds_are_attached_from_their_files_in_place_of_their_earlier_text(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    crowded = tmp_path / "crowded.md"
    crowded.write_text("# head\n\n## ugv: some/run\n\nMade by A.\n\n| row |\n\n### by movers\n\n| m |\n")
    monkeypatch.setattr(generalisation, "EXTRA_GROUNDS", {"ugv": [("Crowded", crowded)]})
    out = tmp_path / "generalisation.md"
    out.write_text("# G\n\n## ugv: run\n\nmain\n\n### The unseen ground\n\nby\n\n## highway: kept\n\nother\n")
    generalisation.attach_extras(out, "ugv")
    first = out.read_text()
    assert "by\n\n### Crowded\n\nMade by A.\n\n| row |\n\n#### by movers\n\n| m |\n\n## highway: kept" in first
    generalisation.attach_extras(out, "ugv")
    assert out.read_text() == first  # attaching again changes nothing
    crowded.write_text(crowded.read_text().replace("Made by A.", "Made by B."))
    generalisation.attach_extras(out, "ugv")
    assert out.read_text() == first.replace("Made by A.", "Made by B.")
    generalisation.attach_extras(out, "highway")  # no extras: left as it is
    assert out.read_text() == first.replace("Made by A.", "Made by B.")
    crowded.write_text("# nothing for ugv\n")
    assert generalisation.main(["--sim", "ugv", "--extras-only", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has no ugv section" in err[0]


def test_cached_episodes_are_keyed_by_what_the_run_folder_holds(tmp_path: Path) -> None:
    """A policy folder refitted in place (another gate, new bounds) must not reuse its old episodes from a cache."""
    import shutil

    folder = tmp_path / "policy"
    shutil.copytree(RUN, folder)
    before = generalisation.cache_run_key(folder)
    assert before.startswith(f"{folder}#") and generalisation.cache_run_key(folder) == before
    config = folder / "config.json"
    config.write_text(config.read_text().replace('"tau_scale": 1.1', '"tau_scale": 1.0'))
    assert generalisation.cache_run_key(folder) != before

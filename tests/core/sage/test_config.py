"""Method presets, overrides from the command line, and round trips through JSON."""

from __future__ import annotations

import json

import pytest

from core.sage.config import METHODS, apply_overrides, for_method, from_dict, to_dict


def test_presets_switch_the_sage_extras() -> None:
    sage, sac, fni, dagger = (for_method(m) for m in ("sage", "sac", "fni-rl", "hg-dagger"))
    assert sage.takeover and sage.imitation and sage.fear_regularisation and sage.gate.use_curiosity
    assert not (sac.world_model or sac.takeover or sac.fear_regularisation or sac.imitation or sac.violation_penalty)
    assert fni.fear_regularisation and fni.violation_penalty and not fni.takeover and not fni.gate.use_curiosity
    assert dagger.takeover and dagger.world_model and not dagger.fear_regularisation
    assert set(METHODS) == {"sage", "sac", "td3", "hg-dagger", "fni-rl"}


def test_a_base_config_keeps_its_hyperparameters_and_takes_the_methods_switches() -> None:
    base = for_method("sac", gamma=0.97, hidden=64)
    base.gate.tau_max = 0.6
    sage = for_method("sage", base=base)
    assert sage.method == "sage" and sage.gamma == 0.97 and sage.hidden == 64 and sage.gate.tau_max == 0.6
    assert sage.takeover and sage.world_model and base.method == "sac" and not base.takeover


def test_overrides_convert_types_and_name_what_is_wrong() -> None:
    cfg = apply_overrides(
        for_method("sage"),
        [
            "gamma=0.95",
            "gate.hold_steps=7",
            "reward_bounds=-1,2",
            "takeover=false",
            "target_entropy=none",
            "gate.aggregate=discounted_mean",
        ],
    )
    assert (cfg.gamma, cfg.gate.hold_steps, cfg.reward_bounds, cfg.takeover) == (0.95, 7, (-1.0, 2.0), False)
    assert cfg.target_entropy is None and cfg.gate.aggregate == "discounted_mean"
    for bad, message in (
        ("nope=1", "nope"),
        ("gate.nope=1", "gate.nope"),
        ("gamma=abc", "gamma"),
        ("gate.aggregate=mean", "aggregate"),
        ("gamma", "key=value"),
        ("gamma=1.5", "gamma"),
        ("world_model=false", "world_model"),
        ("gate.release=1.5", "gate.release"),
        ("gate.release=-0.1", "gate.release"),
        ("world_model_config.cost_label_weight=1.5", "cost_label_weight"),
        ("gate.hold_seconds=1", "step_seconds"),
        ("gate.step_seconds=0", "step_seconds"),
        ("gate.imagined_contact=true", "contact_floors"),
        ("gate.contact_floors=[0.1, -0.2]", "contact_floors"),
        ("bc_weight=-1", "bc_weight"),
        ("bc_weight=nan", "bc_weight"),
    ):
        with pytest.raises(ValueError, match=message):
            apply_overrides(for_method("sage"), [bad])


def test_a_value_of_the_wrong_type_says_what_would_be_read() -> None:
    for bad, expected in (
        ("gate.hold_steps=abc", "gate.hold_steps: cannot read 'abc' as int"),
        ("gamma=x", "gamma: cannot read 'x' as float"),
        ("takeover=perhaps", "takeover: cannot read 'perhaps' as true or false"),
        ("gate.aggregate=mean", "as one of 'max', "),
        ("reward_bounds=1", "as two numbers (low,high)"),
    ):
        with pytest.raises(ValueError) as error:
            apply_overrides(for_method("sage"), [bad])
        assert expected in str(error.value) and "<class" not in str(error.value)


def test_contact_that_needs_the_scan_closing_needs_the_motion_input() -> None:
    with pytest.raises(ValueError, match="motion_input"):
        apply_overrides(
            for_method("sage"), ["world_model_config.motion_input=false", "gate.contact_needs_closing=true"]
        )
    cfg = apply_overrides(for_method("sage"), ["gate.contact_needs_closing=true"])
    assert cfg.gate.contact_needs_closing and not cfg.gate.imagined_contact  # inert until contact is on


def test_json_round_trip() -> None:
    cfg = apply_overrides(for_method("fni-rl"), ["reward_bounds=-1,1", "gate.beta=0.3"])
    again = from_dict(json.loads(json.dumps(to_dict(cfg))))
    assert again == cfg
    with pytest.raises(ValueError, match="unknown config field"):
        from_dict({**to_dict(cfg), "extra": 1})


def test_gate_settings_are_read_as_their_fields_types_and_unknown_ones_refused() -> None:
    from core.sage.config import parse_gate_settings

    settings = parse_gate_settings(["hold_seconds=2", "release = 0", "use_curiosity=false", "aggregate=max"])
    assert settings == {"hold_seconds": 2.0, "release": 0.0, "use_curiosity": False, "aggregate": "max"}
    assert isinstance(settings["hold_seconds"], float)
    for bad, message in (("nope=1", "nope"), ("hold_seconds", "key=value"), ("release=abc", "release")):
        with pytest.raises(ValueError, match=message):
            parse_gate_settings([bad])
    # imagined contact brings the simulator's floors along, unless the settings give their own
    assert parse_gate_settings(["imagined_contact=true"], (0.02, 0.03)) == {
        "imagined_contact": True,
        "contact_floors": [0.02, 0.03],
    }
    assert parse_gate_settings(["imagined_contact=on", "contact_floors=[0.5, 0.25]"], (0.02,))["contact_floors"] == [
        0.5,
        0.25,
    ]
    assert parse_gate_settings(["imagined_contact=false"], (0.02,)) == {"imagined_contact": False}

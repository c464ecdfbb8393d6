"""Headless training on the one step loop: run folders, checkpoints, agent loading, the CLI, and learning."""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from core.agents import NoWorldModelError, list_checkpoints, load_agent, resolve_checkpoint
from core.sage.config import AgentConfig, for_method
from core.train import RunConfig, Trainer, evaluate, gated_episode, returns_to_go, train
from tests.core.sage import envs

torch.set_num_threads(1)


def small(method: str, **overrides: Any) -> AgentConfig:
    """Small networks and early starts, so that a test run takes seconds."""
    settings: dict[str, Any] = dict(
        hidden=32,
        batch_size=32,
        bc_batch_size=32,
        learning_starts=60,
        wm_min_samples=80,
        wm_fit_every=150,
        virtual_every=50,
        virtual_starts=32,
        pretrain_bc_steps=200,
        pretrain_critic_steps=100,
    )
    settings.update(overrides)
    cfg = for_method(method, **settings)
    cfg.world_model_config.hidden = 16
    cfg.world_model_config.max_updates_per_fit = 150
    return cfg


def point_env(scenario: str) -> Any:
    return envs.make(scenario)


@pytest.fixture(scope="module")
def sage_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    out = tmp_path_factory.mktemp("runs") / "sage-point"
    run = RunConfig(
        sim="point", scenarios=["static", "dynamic"], episodes=6, seed=3, demo_episodes=4, checkpoint_every=3
    )
    result = train(run, small("sage"), point_env, out, progress=False)
    return out, result


def test_a_run_folder_holds_config_metrics_and_checkpoints(sage_run) -> None:
    out, result = sage_run
    config = json.loads((out / "config.json").read_text())
    assert set(config) == {"run", "agent", "meta"} and config["agent"]["method"] == "sage"
    assert config["meta"]["episodes"] == 6 and config["meta"]["has_world_model"]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["phase"] for r in rows] == ["demo"] * 4 + ["train"] * 6
    assert [r["scenario"] for r in rows if r["phase"] == "train"] == ["static", "dynamic"] * 3
    assert all(r["takeover_rate"] == 1.0 for r in rows[:4])  # demonstrations: the expert drove throughout
    assert math.isfinite(rows[-1]["mean_fear"]) and "critic_loss" in rows[-1] and "success" in rows[-1]
    assert [p.name for p in list_checkpoints(out)] == ["episode_00003.pt", "episode_00006.pt"]
    assert resolve_checkpoint(out) == out / "checkpoint.pt"
    assert result.learner.buffer.takeover_count() >= sum(r["steps"] for r in rows[:4])


def test_loaded_agent_acts_and_gates_like_the_learner(sage_run) -> None:
    out, result = sage_run
    learner = result.learner
    agent = load_agent(out)
    assert (agent.meta.method, agent.meta.sim, agent.meta.obs_dim, agent.meta.act_dim) == ("sage", "point", 8, 2)
    assert agent.meta.scenarios == ["static", "dynamic"] and agent.has_world_model
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs = rng.normal(size=8).astype(np.float32)
        np.testing.assert_allclose(
            agent.policy.act(obs, deterministic=True), learner.act(obs, deterministic=True), atol=1e-6
        )
        a = agent.policy.act(obs, deterministic=True)
        ours, theirs = agent.make_gate().decide(obs, a), learner.make_gate().decide(obs, a)
        assert ours.fear == pytest.approx(theirs.fear, abs=1e-6)
    gate = agent.make_gate(hold_steps=9, tau_max=0.9)
    assert gate.cfg.hold_steps == 9 and gate.cfg.tau_max == 0.9 and agent.config.gate.hold_steps != 9
    with pytest.raises(ValueError, match="no_such_field"):
        agent.make_gate(no_such_field=1)
    with pytest.raises(ValueError, match="tau_min"):
        agent.make_gate(tau_min=0.9, tau_max=0.1)
    version = load_agent(list_checkpoints(out)[0])
    assert version.meta.episodes == 3


def test_half_precision_checkpoints_are_smaller_and_act_the_same(sage_run, tmp_path: Path) -> None:
    from core.agents import meta_of, save_checkpoint

    out, result = sage_run
    meta = meta_of(torch.load(out / "checkpoint.pt", weights_only=True))
    half = save_checkpoint(tmp_path / "half.pt", result.learner, meta, dtype="float16")
    assert half.stat().st_size < 0.7 * (out / "checkpoint.pt").stat().st_size
    full, small_agent = load_agent(out), load_agent(half)
    obs = np.linspace(-1, 1, 8).astype(np.float32)
    np.testing.assert_allclose(small_agent.policy.act(obs, True), full.policy.act(obs, True), atol=2e-2)


def test_warm_start_takes_the_parts_that_fit(sage_run) -> None:
    out, _ = sage_run
    run = RunConfig(sim="point", scenarios=["dynamic"], episodes=0, init=str(out))
    trainer = Trainer(run, small("sac"), point_env, None, progress=False)
    assert {"actor", "critic", "critic_target"} <= set(trainer.init_parts) and trainer.learner.warm
    trainer = Trainer(run, small("hg-dagger"), point_env, None, progress=False)
    assert {"actor", "world_model"} <= set(trainer.init_parts)


def test_a_world_model_only_refit_changes_the_model_and_nothing_else(sage_run, tmp_path: Path) -> None:
    """``--world-model-only``: the policy drives and its world model is refitted with the new label horizon; the
    actor and critics stay as they were, and the checkpoint keeps the policy's own schedule, so adapting from it
    still learns."""
    init_out, _ = sage_run
    before = load_agent(init_out)
    cfg = copy.deepcopy(before.config)
    cfg.world_model_config.violation_steps = 7
    run = RunConfig(sim="point", scenarios=["dynamic"], episodes=3, seed=5, init=str(init_out), checkpoint_every=0,
                    world_model_only=True)  # fmt: skip
    result = train(run, cfg, point_env, tmp_path / "refit", progress=False)
    assert result.learner.updates == 0
    after = load_agent(tmp_path / "refit")
    for name, value in before.learner.actor.state_dict().items():
        assert torch.equal(value, after.learner.actor.state_dict()[name]), name
    changed = [
        name
        for name, value in before.world_model.state_dict().items()
        if value.is_floating_point() and not torch.equal(value, after.world_model.state_dict()[name])
    ]
    assert changed, "the world model was not refitted"
    assert after.config.updates_per_step == before.config.updates_per_step > 0
    assert after.config.takeover and after.config.method == "sage"
    assert after.config.world_model_config.violation_steps == 7
    ran = json.loads((tmp_path / "refit" / "config.json").read_text())["ran_with"]
    assert ran["updates_per_step"] == 0 and ran["takeover"] is False
    with pytest.raises(ValueError, match="--init"):
        Trainer(dataclasses.replace(run, init=None), cfg, point_env, tmp_path / "no-init", progress=False)


def test_a_world_model_only_run_of_no_episodes_rewrites_the_config_and_nothing_else(sage_run, tmp_path: Path) -> None:
    """How a gate setting is deployed on a committed policy (its README's command): every tensor stays, the
    gate's curiosity average too (a fresh gate would restart it at the model's reference)."""
    init_out, _ = sage_run
    before = torch.load(resolve_checkpoint(init_out), weights_only=False)
    ema = float(before["state"]["gate"]["curiosity_ema"])
    assert not math.isclose(ema, float(load_agent(init_out).world_model.curiosity_ref), rel_tol=1e-3)
    cfg = copy.deepcopy(load_agent(init_out).config)
    cfg.gate.release = 1.0
    run = RunConfig(sim="point", scenarios=["dynamic"], episodes=0, seed=5, init=str(init_out), checkpoint_every=0,
                    world_model_only=True)  # fmt: skip
    train(run, cfg, point_env, tmp_path / "deploy", progress=False)
    after = torch.load(resolve_checkpoint(tmp_path / "deploy"), weights_only=False)
    assert after["state"].keys() == before["state"].keys()
    for part, value in before["state"].items():
        if part == "optimizers":
            continue
        tensors = value if isinstance(value, dict) else {"": value}
        for name, tensor in tensors.items():
            if torch.is_tensor(tensor):
                assert torch.equal(tensor, after["state"][part][name] if name else after["state"][part]), (part, name)
    assert float(after["state"]["gate"]["curiosity_ema"]) == ema
    assert load_agent(tmp_path / "deploy").config.gate.release == 1.0


def test_a_refit_drives_its_gated_share_of_episodes_as_deployed(sage_run, tmp_path: Path) -> None:
    """``refit_gated_share``: that share of a refit's episodes (of each scenario, spread evenly) runs the policy
    with its gate handing control to the expert, so takeovers and hand-backs reach the model's data; the others
    run the policy alone, with nobody to take over. A threshold of 0 makes the gate fire at every step."""
    init_out, _ = sage_run
    cfg = copy.deepcopy(load_agent(init_out).config)
    cfg.gate.tau_from_data, cfg.gate.tau_min, cfg.gate.tau_max = False, 0.0, 0.0
    run = RunConfig(sim="point", scenarios=["static", "dynamic"], episodes=8, seed=5, init=str(init_out),
                    checkpoint_every=0, world_model_only=True, refit_gated_share=0.5)  # fmt: skip
    result = train(run, cfg, point_env, tmp_path / "refit", progress=False)
    rows = result.rows
    assert [r["scenario"] for r in rows] == ["static", "dynamic"] * 4
    assert [r["expert_behind_gate"] for r in rows] == [False, False, True, True] * 2
    assert all(r["takeover_rate"] > 0.9 for r in rows if r["expert_behind_gate"])
    assert all(r["takeover_rate"] == 0.0 for r in rows if not r["expert_behind_gate"])
    assert result.learner.updates == 0 and result.learner.buffer.takeover_count() > 0
    with pytest.raises(ValueError, match="world-model-only"):
        Trainer(dataclasses.replace(run, world_model_only=False), cfg, point_env, None, progress=False)
    with pytest.raises(ValueError, match="refit_gated_share"):
        Trainer(dataclasses.replace(run, refit_gated_share=1.5), cfg, point_env, None, progress=False)


def test_gated_episodes_are_spread_evenly() -> None:
    for share, n in [(0.0, 0), (0.3, 3), (0.5, 5), (1.0, 10)]:
        picked = [gated_episode(k, share) for k in range(10)]
        assert sum(picked) == n, share
    assert [gated_episode(k, 0.5) for k in range(4)] == [False, True, False, True]


def test_a_world_model_only_refit_records_the_model_it_fitted(sage_run, tmp_path: Path) -> None:
    """Given a preset without the world-model switch (``--method sac``), the refit's checkpoint still says it holds
    a world model, so that fine-tuning from it keeps its gate."""
    init_out, _ = sage_run
    cfg = small("sac")
    cfg.world_model = False
    run = RunConfig(sim="point", scenarios=["dynamic"], episodes=2, seed=5, init=str(init_out), checkpoint_every=0,
                    world_model_only=True)  # fmt: skip
    train(run, cfg, point_env, tmp_path / "refit", progress=False)
    after = load_agent(tmp_path / "refit")
    assert after.config.world_model and after.has_world_model and after.config.method == "sac"


def test_bad_paths_and_runs_without_a_world_model_fail_clearly(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no run folder"):
        load_agent(tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match="not a run folder"):
        load_agent(tmp_path)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a readable SAGE checkpoint"):
        load_agent(junk)
    torch.save({"hello": 1}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a SAGE checkpoint"):
        load_agent(tmp_path / "other.pt")
    out = tmp_path / "sac"
    train(
        RunConfig(sim="point", scenarios=["static"], episodes=1, checkpoint_every=0),
        small("sac"),
        point_env,
        out,
        progress=False,
    )
    agent = load_agent(out)
    assert not agent.has_world_model
    with pytest.raises(NoWorldModelError, match="no trained world model"):
        agent.make_gate()


def test_evaluation_runs_the_policy_alone_on_fresh_seeds(sage_run) -> None:
    out, _ = sage_run
    agent = load_agent(out)
    results = evaluate(agent.policy, point_env, ["static"], episodes=3, progress=False)
    rows = results["static"]
    assert len(rows) == 3 and all(r["takeovers"] == 0 for r in rows) and all(math.isnan(r["mean_fear"]) for r in rows)
    gated = evaluate(agent.policy, point_env, ["static"], episodes=2, gate_factory=agent.make_gate, progress=False)
    assert all(math.isfinite(r["mean_fear"]) and r["takeovers"] == 0 for r in gated["static"])


def test_returns_to_go_restart_at_episode_ends() -> None:
    g = returns_to_go(np.array([1.0, 1.0, 1.0, 2.0]), np.array([0, 0, 1, 0.0]), np.array([0, 0, 1, 1], bool), 0.5)
    np.testing.assert_allclose(g, [1.75, 1.5, 1.0, 2.0])


# -- the CLI -------------------------------------------------------------------------------------------
@pytest.fixture
def point_sim(monkeypatch: pytest.MonkeyPatch) -> None:
    import sims

    monkeypatch.setitem(sims.SIMULATORS, "point", "tests.core.sage.envs")  # its DESCRIPTOR is all it takes


def test_cli_train_and_eval_of_one_run_and_of_several(point_sim, tmp_path: Path) -> None:
    from app.cli import app

    cli = CliRunner()
    first, second = tmp_path / "a", tmp_path / "b"
    common = [
        "train",
        "--sim",
        "point",
        "--scenario",
        "static",
        "--episodes",
        "2",
        "--quiet",
        "--set",
        "hidden=16",
        "--set",
        "learning_starts=20",
        "--set",
        "batch_size=16",
    ]
    result = cli.invoke(app, [*common, "--method", "sac", "--out", str(first)])
    assert result.exit_code == 0, result.output
    assert "run folder" in result.output and (first / "checkpoint.pt").is_file()
    result = cli.invoke(app, [*common, "--method", "td3", "--out", str(second), "--seed", "1"])
    assert result.exit_code == 0, result.output
    result = cli.invoke(app, ["eval", str(first), "--episodes", "2", "--quiet"])
    assert result.exit_code == 0, result.output
    assert "a (point static)" in result.output and "success" in result.output and "return" in result.output
    result = cli.invoke(
        app,
        [
            "eval",
            str(first),
            str(second),
            "--episodes",
            "2",
            "--scenario",
            "dynamic",
            "--quiet",
            "--save",
            str(tmp_path / "rows.jsonl"),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "a (point dynamic)" in result.output and "b (point dynamic)" in result.output
    assert len((tmp_path / "rows.jsonl").read_text().splitlines()) == 4


def test_a_hold_in_seconds_is_counted_in_the_steps_of_the_simulator_the_run_trained_on(
    point_sim, tmp_path: Path
) -> None:
    """``--set gate.hold_seconds``: the run records its simulator's step (the point sim's 0.1 s), so the expert
    holds control 0.3 s = 3 steps there; an explicit ``hold_steps`` of a loaded run's gate is the hold again."""
    from app.cli import app

    out = tmp_path / "held"
    args = ["train", "--sim", "point", "--scenario", "static", "--episodes", "1", "--method", "sac", "--quiet"]
    result = CliRunner().invoke(app, [*args, "--set", "hidden=16", "--set", "gate.hold_seconds=0.3", "--out", str(out)])
    assert result.exit_code == 0, result.output
    gate = load_agent(out).config.gate
    assert (gate.step_seconds, gate.hold_seconds, gate.hold, gate.hold_steps) == (0.1, 0.3, 3, 5)
    assert load_agent(out).gate_config(hold_steps=2).hold == 2
    assert load_agent(out).gate_config(hold_seconds=1.0).hold == 10
    result = CliRunner().invoke(app, [*args, "--set", "gate.hold_seconds=0", "--out", str(tmp_path / "zero")])
    assert result.exit_code == 2 and "hold_seconds" in result.output


def test_a_run_records_its_simulators_contact_floors_for_fear_s_imagined_contact(
    point_sim, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Every training run writes its simulator's contact floors into its gate, as it writes the step: a run trained
    with imagined contact on has them, and one on a simulator that declares none cannot switch it on."""
    import dataclasses

    from app.cli import app
    from tests.core.sage import envs

    args = ["train", "--sim", "point", "--scenario", "static", "--episodes", "1", "--method", "sac", "--quiet"]
    args += ["--set", "hidden=16", "--set", "gate.imagined_contact=true"]
    result = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "none")])
    assert result.exit_code == 2 and "contact_floors" in result.output
    monkeypatch.setattr(envs, "DESCRIPTOR", dataclasses.replace(envs.DESCRIPTOR, contact_floors=(0.1, 0.2)))
    result = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "floors")])
    assert result.exit_code == 0, result.output
    gate = load_agent(tmp_path / "floors").config.gate
    assert gate.imagined_contact and gate.contact_floors == [0.1, 0.2]


def test_eval_drives_with_the_gate_settings_it_is_given(point_sim, sage_run, tmp_path: Path) -> None:
    """``sage eval --gate --expert --set gate.KEY=VALUE``: a threshold pinned at 0 hands every step to the expert, one
    pinned out of reach none; wrong settings are refused by name."""
    from app.cli import app

    run, _ = sage_run
    pinned = ["--set", "gate.tau_from_data=false", "--set", "gate.use_curiosity=false"]

    def takeover(level: str) -> float:
        rows = tmp_path / f"rows-{level}.jsonl"
        args = ["eval", str(run), "--scenario", "dynamic", "--episodes", "2", "--gate", "--expert", "--quiet"]
        gate = [*pinned, "--set", f"gate.tau_min={level}", "--set", f"gate.tau_max={level}"]
        result = CliRunner().invoke(app, [*args, *gate, "--save", str(rows)])
        assert result.exit_code == 0, result.output
        return float(np.mean([json.loads(line)["takeover_rate"] for line in rows.read_text().splitlines()]))

    assert takeover("0") == 1.0 and takeover("1000") == 0.0
    for bad, message in ((["--set", "gate.nope=1"], "nope"), (["--set", "gate.release=2"], "release")):
        result = CliRunner().invoke(app, ["eval", str(run), "--scenario", "dynamic", "--gate", *bad])
        assert result.exit_code == 2 and message in result.output, result.output
    result = CliRunner().invoke(app, ["eval", str(run), "--scenario", "dynamic", "--set", "gate.release=0"])
    assert result.exit_code == 2 and "needs --gate" in result.output


def test_cli_refuses_bad_input_by_name(point_sim, tmp_path: Path) -> None:
    from app.cli import app

    cli = CliRunner()
    result = cli.invoke(app, ["train", "--sim", "point", "--method", "ppo", "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "unknown method" in result.output
    result = cli.invoke(app, ["train", "--sim", "point", "--set", "gamma=2", "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "gamma" in result.output
    result = cli.invoke(app, ["train", "--sim", "nosuchsim", "--episodes", "1", "--out", str(tmp_path / "y")])
    assert result.exit_code != 0 and "nosuchsim" in result.output
    result = cli.invoke(app, ["eval", str(tmp_path / "missing")])
    assert result.exit_code == 2 and "missing" in result.output


# -- UGV: SAGE adapting the committed default policy to a dynamic scenario ------------------------------
DEFAULT_POLICY = Path(__file__).resolve().parents[2] / "policies" / "ugv-default"


def ugv_env(scenario: str) -> Any:
    import sims

    return sims.make("ugv", scenario=int(scenario))


def adapt(method: str, episodes: int, seed: int = 1, **overrides: Any) -> list[dict[str, Any]]:
    """Warm-start ``method`` from the default policy (and its hyperparameters) on UGV scenario 3."""
    from core.agents import load_checkpoint
    from core.sage.config import from_dict

    base = from_dict(load_checkpoint(DEFAULT_POLICY)["agent_config"])
    cfg = for_method(method, base=base, **overrides)
    run = RunConfig(
        sim="ugv", scenarios=["3"], episodes=episodes, seed=seed, init=str(DEFAULT_POLICY), checkpoint_every=0
    )
    return train(run, cfg, ugv_env, None, progress=False).rows


def test_sage_on_a_dynamic_ugv_scenario_takes_over_and_learns_from_it() -> None:
    """The fast version of the adaptation run below: the same path (default policy, gate on its world model,
    scripted expert, refit on the new scenario, value-weighted imitation of the takeovers), three episodes."""
    rows = adapt("sage", episodes=3, updates_per_step=0.25, wm_min_samples=150)
    assert sum(r["takeovers"] for r in rows) > 0
    assert all(math.isfinite(r["mean_fear"]) and math.isfinite(r["mean_curiosity"]) for r in rows)
    last = rows[-1]
    assert math.isfinite(last["bc_loss"]) and math.isfinite(last["omega_mean"]) and "wm_holdout_nll" in last


@pytest.mark.slow
def test_sage_takes_over_less_as_it_adapts_and_collides_no_more_than_sac() -> None:
    episodes = 40
    sage, sac = adapt("sage", episodes), adapt("sac", episodes)
    quarter = episodes // 4
    first = np.mean([r["takeover_rate"] for r in sage[:quarter]])
    last = np.mean([r["takeover_rate"] for r in sage[-quarter:]])
    assert last < first
    assert sum(r["collision"] for r in sage) <= sum(r["collision"] for r in sac)


class _ConstantPlanner:
    """A planner that always commands the same action (the demonstrations' own expert in the test below)."""

    ACTION = 0.123

    def __init__(self, env: Any) -> None:
        self.shape = env.action_space.shape

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        return np.full(self.shape, self.ACTION, np.float32)


def test_demonstrations_come_from_the_demo_expert_and_takeovers_from_the_expert(sage_run, tmp_path: Path) -> None:
    """``demo_expert``: the demonstrations are driven by that expert (here a planner that always commands 0.123),
    the takeovers of the same run by the run's own expert (the point world's scripted one)."""
    from core.planners import register_planner, unregister_planner

    init_out, _ = sage_run
    cfg = copy.deepcopy(load_agent(init_out).config)
    cfg.gate.tau_from_data, cfg.gate.tau_min, cfg.gate.tau_max = False, 0.0, 0.0  # the gate fires at every step
    register_planner("test-constant", _ConstantPlanner, replace=True)
    try:
        run = RunConfig(sim="point", scenarios=["static"], episodes=2, seed=5, init=str(init_out), demo_episodes=2,
                        checkpoint_every=0, world_model_only=True, refit_gated_share=1.0,
                        demo_expert="test-constant")  # fmt: skip
        result = train(run, cfg, point_env, tmp_path / "refit", progress=False)
    finally:
        unregister_planner("test-constant")
    buffer = result.learner.buffer
    demo_steps = sum(int(row["steps"]) for row in result.demo_rows)
    assert demo_steps > 0 and buffer.size > demo_steps
    assert np.all(buffer.action[:demo_steps] == np.float32(_ConstantPlanner.ACTION))
    takeovers = buffer.takeover[demo_steps : buffer.size]
    assert takeovers.any()
    expert_actions = buffer.a_expert[demo_steps : buffer.size][takeovers]
    assert not np.any(np.all(expert_actions == np.float32(_ConstantPlanner.ACTION), axis=1))
    meta = json.loads((tmp_path / "refit" / "config.json").read_text())
    assert meta["run"]["demo_expert"] == "test-constant" and meta["run"]["expert"] is None


def test_a_planner_for_another_simulator_is_refused_before_the_run(tmp_path: Path) -> None:
    """An expert (or demonstrations' expert) that cannot drive the run's simulator is a config error at the start,
    not an error row per episode."""
    from core.planners import register_planner, unregister_planner

    register_planner("test-elsewhere", _ConstantPlanner, sims=("ugv",), replace=True)
    try:
        for field in ("expert", "demo_expert"):
            run = RunConfig(sim="point", scenarios=["static"], episodes=1, demo_episodes=1, **{field: "test-elsewhere"})
            with pytest.raises(ValueError, match="drives ugv, not point"):
                Trainer(run, small("sage"), point_env, tmp_path / field, progress=False)
    finally:
        unregister_planner("test-elsewhere")


def test_device_cpu_trains_records_the_device_and_loads_with_map_location(tmp_path: Path) -> None:
    """``--device cpu`` (and ``auto`` on a machine without CUDA) trains as before; the run records the device asked
    for, and its checkpoint is device-free: it loads with ``map_location="cpu"`` and acts."""
    run = RunConfig(sim="point", scenarios=["static"], episodes=2, seed=1, demo_episodes=2, device="cpu")
    train(run, small("sage"), point_env, tmp_path / "cpu", progress=False)
    assert json.loads((tmp_path / "cpu" / "config.json").read_text())["run"]["device"] == "cpu"
    payload = torch.load(resolve_checkpoint(tmp_path / "cpu"), map_location="cpu", weights_only=True)
    assert all(t.device.type == "cpu" for t in payload["state"]["actor"].values())
    agent = load_agent(tmp_path / "cpu")
    assert agent.learner.device.type == "cpu"
    assert np.isfinite(agent.policy.act(np.zeros(agent.meta.obs_dim, np.float32), deterministic=True)).all()


def test_device_cuda_without_cuda_and_a_cuda_graph_off_cuda_fail_before_any_episode(tmp_path: Path) -> None:
    from core.device import DeviceError

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    run = RunConfig(sim="point", scenarios=["static"], episodes=1, device="cuda")
    with pytest.raises(DeviceError, match="no CUDA device"):
        Trainer(run, small("sac"), point_env, None, progress=False)
    with pytest.raises(DeviceError, match="needs --device cuda"):
        Trainer(dataclasses.replace(run, device="auto"), small("sac", cuda_graph=True), point_env, None, progress=False)


def test_a_warm_start_into_critics_of_another_shape_fits_them_to_the_saved_ones_before_learning(sage_run) -> None:
    """``sage train --init`` with layer-normed critics on a base saved without them (no demonstrations, so no
    pretraining): the first update fits the new critics to the saved ones before its TD step."""
    out, _ = sage_run
    cfg = small("sac")
    cfg.critic_layer_norm = True
    run = RunConfig(sim="point", scenarios=["dynamic"], episodes=0, init=str(out))
    learner = Trainer(run, cfg, point_env, None, progress=False).learner
    teacher = learner.critic_teacher
    assert teacher is not None and not teacher.layer_norm and learner.critic.layer_norm
    rng = np.random.default_rng(0)
    for _ in range(cfg.batch_size + 10):
        learner.buffer.add(rng.normal(size=learner.obs_dim).astype(np.float32),
                           rng.uniform(-1, 1, learner.act_dim).astype(np.float32), 0.0,
                           rng.normal(size=learner.obs_dim).astype(np.float32), False)  # fmt: skip
    batch = learner.buffer.sample(64, learner.rng)
    with torch.no_grad():
        before = float((learner.critic(batch.obs, batch.action) - teacher(batch.obs, batch.action)).pow(2).mean())
    learner.update()
    assert learner.critic_teacher is None
    with torch.no_grad():
        after = float((learner.critic(batch.obs, batch.action) - teacher(batch.obs, batch.action)).pow(2).mean())
    assert after < 0.2 * before, (after, before)

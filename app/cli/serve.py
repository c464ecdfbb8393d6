"""``sage serve``: the live dashboard (FastAPI + viser) on the one step loop."""

from __future__ import annotations

import errno
import gc
import socket
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer

from app.cli.options import (
    FINETUNE_SECTIONS,
    GATE_SECTIONS,
    GATE_SET_HELP,
    LEARNER_SECTIONS,
    GateSetRetired,
    RegressionAgainstOption,
    checked_regression_against,
    checked_scenarios,
    one_scenario,
    policy_sim,
    refuse_retired,
    routed_settings,
)
from app.messages import EXPERT_MODES
from core.dotted import Section

if TYPE_CHECKING:
    from core.finetune import FinetuneConfig

SERVE_SECTIONS: dict[str, Section] = {**GATE_SECTIONS, **FINETUNE_SECTIONS, **LEARNER_SECTIONS}
"""``sage serve --set``: the gate's settings, and the fine-tuning worker's (its rounds', and its learner's over SAGE's
adaptation switches, as ``sage cycles`` takes them; the learner's need their section's name here)."""
SERVE_SET_HELP = (
    f"For each policy: {GATE_SET_HELP} For the fine-tuning worker: finetune.KEY=VALUE, a setting of its rounds "
    "(core.finetune.FinetuneConfig, e.g. finetune.prior_distill=5), and learner.KEY=VALUE or world_model.KEY=VALUE, "
    "the learner its rounds train (over SAGE's switches, e.g. learner.bc_weight=10)."
)


def register(app: typer.Typer) -> None:
    """Add ``sage serve`` to ``app``."""

    @app.command()
    def serve(
        host: Annotated[str, typer.Option(help="Address to bind; the default keeps the dashboard on this machine.")] = (
            "127.0.0.1"
        ),
        port: Annotated[int, typer.Option(help="Port of the dashboard (viser gets its own loopback port).")] = 8000,
        sim: Annotated[
            str | None, typer.Option(help="Simulator to open on (default: the --policy run's own, else ugv).")
        ] = None,
        scenario: Annotated[
            list[str] | None,
            typer.Option(help="Scenario name of the simulator (one; e.g. 3, c2, test-adversarial, a UGV .yaml file)."),
        ] = None,
        policy: Annotated[
            str | None,
            typer.Option(
                help="Run folder or checkpoint to drive with; default: policies/<sim>-default, or the "
                "scripted expert when there is none. 'scripted' runs the scripted expert."
            ),
        ] = None,
        expert: Annotated[
            str,
            typer.Option(
                help="Who answers a takeover: person (the page asks you, and the scripted fallback drives until you "
                "take hold with Space), person_fallback (the scripted expert answers; you may take over at any time) "
                "or scripted (the scripted expert only)."
            ),
        ] = "person",
        speed: Annotated[float, typer.Option(min=0.1, max=20.0, help="Wall-clock speed multiplier.")] = 1.0,
        sessions: Annotated[Path, typer.Option(help="Folder where every live step is recorded.")] = Path("sessions"),
        paused: Annotated[bool, typer.Option(help="Start with the loop paused.")] = False,
        allow_host: Annotated[
            list[str] | None,
            typer.Option(help="Another host name the page may be opened under (serving on a LAN); repeatable."),
        ] = None,
        finetune: Annotated[
            bool, typer.Option(help="Fine-tune a trained policy on the session in a worker process.")
        ] = True,
        set_: Annotated[list[str] | None, typer.Option("--set", help=SERVE_SET_HELP)] = None,
        regression_scenario: Annotated[
            list[str] | None,
            typer.Option(
                help="A regression test against forgetting (repeatable, e.g. the policy's own 1 and 2): a fine-tuned "
                "version drives only if, ALONE on this scenario's fixed seeds, it succeeds in as many episodes as the "
                "policy the session started from (core.promotion)."
            ),
        ] = None,
        regression_against: RegressionAgainstOption = "base",
        gate_set: GateSetRetired = None,
    ) -> None:
        """Serve the live dashboard: the SAGE loop at wall-clock rate, its fear / curiosity / threshold
        charts, keyboard and gamepad takeover, recorded sessions and replays."""
        import logging

        import uvicorn

        from app.server import ServerSettings, create_app
        from core.promotion import PromotionConfig

        if expert not in EXPERT_MODES:
            _fail(f"--expert must be one of {', '.join(EXPERT_MODES)}, not {expert!r}")
        refuse_retired(gate_set=gate_set)
        scenario_name, sim = one_scenario(scenario, "sage serve"), policy_sim(policy, sim)
        routed = routed_settings(set_, SERVE_SECTIONS)
        gate_settings = _check_startup(sim, scenario_name, policy, routed.get("gate", []))
        rounds = _check_finetune(sim, policy, finetune, routed.get("finetune", []), routed.get("learner", []))
        regression = checked_scenarios(sim, regression_scenario or [], "--regression-scenario")
        against = checked_regression_against(regression_against)
        # bound here, before the banner, the loop, the worker or a session exist: a busy or forbidden port is one
        # line now, not uvicorn's error after a session was recorded; uvicorn then serves on this very socket
        listener = bind_listener(host, port)
        port = listener.getsockname()[1]  # --port 0: the port the system chose
        logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
        settings = ServerSettings(
            host=host,
            port=port,
            sim=sim,
            scenario=scenario_name,
            policy=policy,
            expert_mode=expert,  # type: ignore[arg-type]
            speed=speed,
            sessions=sessions,
            start_paused=paused,
            finetune=finetune,
            finetune_config=rounds,
            allow_hosts=list(allow_host or []),
            gate_settings=gate_settings,
            promotion=PromotionConfig(
                regression_scenarios=regression,
                regression_against=against,
            ),
            worker_stop_wait=0.5,
        )
        typer.echo(f"SAGE dashboard on http://{host}:{port}/  (Ctrl+C to stop)")
        # open pages keep their websockets: give them a second to close, not an open-ended wait, on Ctrl+C
        config = uvicorn.Config(
            create_app(settings), log_level="warning", ws_max_size=1 << 20, timeout_graceful_shutdown=1
        )
        try:
            uvicorn.Server(config).run(sockets=[listener])
        except KeyboardInterrupt:  # uvicorn raises the Ctrl+C it handled again, once the lifespan closed down
            code = 130
        else:
            code = 0
        # the lifespan has closed what the server owns (the session's file, the fine-tuning worker, viser); the
        # interpreter's teardown then collected torch's and the simulators' module graphs for seconds (8 s on a
        # loaded machine): frozen, the objects are left to the process's end and Ctrl+C ends it in about one
        gc.freeze()
        raise typer.Exit(code)


def bind_listener(host: str, port: int) -> socket.socket:
    """A TCP socket bound to ``host:port`` (what uvicorn would bind), or one clear line and exit 2 when it
    cannot be: a port out of 0..65535, a host that does not resolve or is not this machine's, a port in use or
    one this user may not bind."""
    if not 0 <= port <= 65535:
        _fail(f"--port {port} is not a port: choose one in 1..65535 (e.g. --port 8000)")
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
    except (socket.gaierror, UnicodeError) as exc:
        reason = getattr(exc, "strerror", None) or exc
        _fail(f"--host {host!r} does not resolve ({reason}): give an address such as 127.0.0.1")
    listener = socket.socket(family, kind, proto)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn: a restart reuses the port at once
    try:
        listener.bind(address)
    except OSError as exc:
        listener.close()
        where = f"{host}:{port}"
        if exc.errno == errno.EADDRINUSE:
            _fail(f"{where} is in use (another sage serve?): stop that server or choose another --port")
        if exc.errno == errno.EACCES:
            _fail(f"not allowed to bind {where} (ports below 1024 need root): choose --port 1024 or above, e.g. 8000")
        if exc.errno == errno.EADDRNOTAVAIL:
            _fail(f"--host {host} is not an address of this machine: use 127.0.0.1, 0.0.0.0 or one of its own")
        _fail(f"cannot bind {where}: {exc.strerror or exc}")
    return listener  # not inheritable: a worker process must never keep the dashboard's port after the server


def _fail(message: str) -> NoReturn:
    """One clear line on stderr, before any banner, and a non-zero exit."""
    typer.secho(f"sage serve: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def _check_startup(sim: str, scenario: str | None, policy: str | None, gate_set: list[str]) -> dict[str, Any]:
    """Refuse a bad simulator, scenario, policy or gate setting before the server starts (one line each, no
    traceback); returns the gate settings, parsed and checked against the policy the dashboard opens on."""
    import sims
    from app.policies import SCRIPTED, default_policy
    from app.server import ServerSettings
    from core.agents import load_agent, load_checkpoint, meta_of
    from core.sage.config import parse_gate_settings

    try:
        sims.descriptor(sim).scenario_kwargs(scenario)
    except ValueError as exc:
        _fail(str(exc))
    if policy is not None and policy != "scripted":
        try:
            trained_on = meta_of(load_checkpoint(policy)).sim
        except (OSError, ValueError, KeyError, TypeError) as exc:
            _fail(f"policy {policy!r} cannot be loaded: {_first_line(exc)}")
        if trained_on != sim:
            _fail(
                f"policy {policy!r} was trained on {trained_on}, not {sim}: give --sim {trained_on}, or a {sim} "
                f"policy (e.g. --policy {Path('policies') / f'{sim}-default'})"
            )
    try:
        settings = parse_gate_settings(gate_set, sims.descriptor(sim).contact_floors)
    except ValueError as exc:
        _fail(f"--set gate.…: {exc}")
    opening = policy or default_policy(ServerSettings().policy_roots, sim)  # where the dashboard will look
    if settings and opening != SCRIPTED and Path(opening).exists():
        try:
            agent = load_agent(opening)
            if agent.has_world_model:
                agent.gate_config(**settings)
        except ValueError as exc:
            _fail(f"--set gate.…: {_first_line(exc)}")
    if opening != SCRIPTED and Path(opening).exists():
        _warm_gate(opening)
    return settings


def _check_finetune(
    sim: str, policy: str | None, finetune: bool, round_pairs: list[str], learner_pairs: list[str]
) -> FinetuneConfig:
    """The fine-tuning worker's settings from ``--set finetune.KEY=VALUE`` and the learner's ``--set learner.…``: one
    line, before the server starts, for an unknown or unreadable one, or for settings no round would take (no
    fine-tuning, or the scripted expert); the learner's are checked on the configuration the rounds of the policy the
    dashboard opens on would train (its own, with SAGE's adaptation switches)."""
    import dataclasses

    from app.policies import SCRIPTED, default_policy
    from app.server import ServerSettings
    from core.agents import load_checkpoint
    from core.finetune import FinetuneConfig, adaptation_config
    from core.learners import learner_entry
    from core.sage.config import apply_overrides, from_dict

    if not round_pairs and not learner_pairs:
        return FinetuneConfig()
    given = ("finetune." if round_pairs else "learner.") + (round_pairs or learner_pairs)[0]
    if not finetune:
        _fail(f"--set {given}: --no-finetune runs no fine-tuning rounds to take it")
    opening = policy or default_policy(ServerSettings().policy_roots, sim)
    if opening == SCRIPTED or not Path(opening).exists():
        _fail(f"--set {given}: the scripted expert is not fine-tuned; give a trained --policy")
    try:
        config = dataclasses.replace(FinetuneConfig().with_settings(round_pairs), overrides=tuple(learner_pairs))
    except ValueError as exc:
        _fail(f"--set finetune.…: {_first_line(exc)}")
    try:
        trained = from_dict(load_checkpoint(opening)["agent_config"])
        rounds = apply_overrides(adaptation_config(trained) if config.adapt_as_sage else trained, list(learner_pairs))
        learner_entry(rounds.method).cls.check_config(rounds)
    except (ValueError, TypeError, KeyError) as exc:
        _fail(f"--set learner.…: {_first_line(exc)}")
    return config


def _warm_gate(policy: str) -> None:
    """The gate's compiled kernel built now, before the loop starts: a fresh install compiles it once (seconds),
    which must not freeze the first steps of the live loop. A policy whose gate cannot be built here is left for
    the loop to report."""
    from core.agents import warm_gate_kernels

    try:
        warm_gate_kernels([policy])
    except Exception as exc:  # the dashboard shows what a broken policy does; start-up only warms
        typer.echo(f"warning: the gate of {policy} was not warmed: {_first_line(exc)}", err=True)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__

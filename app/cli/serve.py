"""``sage serve``: the live dashboard (FastAPI + viser) on the one step loop."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from app.cli.options import GATE_SET_HELP, GateSetRetired, gate_pairs, one_scenario, policy_sim, refuse_retired
from app.messages import EXPERT_MODES


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
        expert: Annotated[str, typer.Option(help=f"Who answers a takeover: {', '.join(EXPERT_MODES)}.")] = "person",
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
        set_: Annotated[list[str] | None, typer.Option("--set", help=f"For each policy: {GATE_SET_HELP}")] = None,
        gate_set: GateSetRetired = None,
    ) -> None:
        """Serve the live dashboard: the SAGE loop at wall-clock rate, its fear / curiosity / threshold
        charts, keyboard and gamepad takeover, recorded sessions and replays."""
        import logging

        import uvicorn

        from app.server import ServerSettings, create_app

        if expert not in EXPERT_MODES:
            _fail(f"--expert must be one of {', '.join(EXPERT_MODES)}, not {expert!r}")
        refuse_retired(gate_set=gate_set)
        scenario_name, sim = one_scenario(scenario, "sage serve"), policy_sim(policy, sim)
        gate_settings = _check_startup(sim, scenario_name, policy, gate_pairs(set_))
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
            allow_hosts=list(allow_host or []),
            gate_settings=gate_settings,
        )
        typer.echo(f"SAGE dashboard on http://{host}:{port}/  (Ctrl+C to stop)")
        uvicorn.run(create_app(settings), host=host, port=port, log_level="warning", ws_max_size=1 << 20)


def _fail(message: str) -> None:
    """One clear line on stderr, before any banner, and a non-zero exit."""
    typer.secho(f"sage serve: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def _check_startup(sim: str, scenario: str | None, policy: str | None, gate_set: list[str]) -> dict[str, Any]:
    """Refuse a bad simulator, scenario, policy or gate setting before the server starts (one line each, no
    traceback); returns the gate settings, parsed and checked against the policy the dashboard opens on."""
    import sims
    from app.policies import SCRIPTED, default_policy
    from app.server import ServerSettings
    from core.agents import load_agent, load_checkpoint
    from core.sage.config import parse_gate_settings

    try:
        sims.descriptor(sim).scenario_kwargs(scenario)
    except ValueError as exc:
        _fail(str(exc))
    if policy is not None and policy != "scripted":
        try:
            load_checkpoint(policy)
        except (OSError, ValueError) as exc:
            _fail(f"policy {policy!r} cannot be loaded: {_first_line(exc)}")
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
    return settings


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__

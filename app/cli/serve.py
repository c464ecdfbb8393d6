"""``sage serve``: the live dashboard (FastAPI + viser) on the one step loop."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from app.messages import EXPERT_MODES


def register(app: typer.Typer) -> None:
    """Add ``sage serve`` to ``app``."""

    @app.command()
    def serve(
        host: Annotated[str, typer.Option(help="Address to bind; the default keeps the dashboard on this machine.")] = (
            "127.0.0.1"
        ),
        port: Annotated[int, typer.Option(help="Port of the dashboard (viser gets its own loopback port).")] = 8000,
        sim: Annotated[str, typer.Option(help="Simulator to open on: ugv, highway or sumo.")] = "ugv",
        scenario: Annotated[int, typer.Option(help="Scenario of the simulator.")] = 1,
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
        finetune: Annotated[
            bool, typer.Option(help="Fine-tune a trained policy on the session in a worker process.")
        ] = True,
    ) -> None:
        """Serve the live dashboard: the SAGE loop at wall-clock rate, its fear / curiosity / threshold
        charts, keyboard and gamepad takeover, recorded sessions and replays."""
        import logging

        import uvicorn

        from app.server import ServerSettings, create_app

        if expert not in EXPERT_MODES:
            raise typer.BadParameter(f"--expert must be one of {', '.join(EXPERT_MODES)}, not {expert!r}")
        logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
        settings = ServerSettings(
            host=host,
            port=port,
            sim=sim,
            scenario=scenario,
            policy=policy,
            expert_mode=expert,  # type: ignore[arg-type]
            speed=speed,
            sessions=sessions,
            start_paused=paused,
            finetune=finetune,
        )
        typer.echo(f"SAGE dashboard on http://{host}:{port}/  (Ctrl+C to stop)")
        uvicorn.run(create_app(settings), host=host, port=port, log_level="warning", ws_max_size=1 << 20)

"""``sage export``: a recorded session as a Minari dataset."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from core.sessions import SessionError, SessionStore


def _simulator_spaces(sim: str) -> tuple[Any, Any]:
    """The simulator's own observation and action spaces, or (None, None) when it cannot be built here."""
    import sims

    try:
        env = sims.make(sim)
    except Exception:
        return None, None
    try:
        return env.observation_space, env.action_space
    finally:
        env.close()


def register(app: typer.Typer) -> None:
    @app.command("export")
    def export(
        session: Annotated[
            str, typer.Argument(help="Session id (see the dashboard's sessions list or --sessions DIR).")
        ],
        minari: Annotated[str, typer.Option(help="Minari dataset name, e.g. sage/ugv/takeovers (-v0 added).")],
        sessions: Annotated[Path, typer.Option(help="Folder of recorded sessions.")] = Path("sessions"),
        root: Annotated[
            Path | None, typer.Option(help="Minari datasets folder (default: MINARI_DATASETS_PATH or ~/.minari).")
        ] = None,
    ) -> None:
        """Write SESSION as a Minari dataset: observations, executed actions, rewards, terminations,
        truncations; takeover flag, agent and expert actions, fear, curiosity and threshold in infos."""
        from core.export import export_minari

        store = SessionStore(sessions)
        try:
            info = store.info(session)
        except SessionError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from exc
        observation_space, action_space = _simulator_spaces(info.sim)
        try:
            dataset = export_minari(
                store,
                session,
                minari,
                observation_space=observation_space,
                action_space=action_space,
                datasets_root=root,
            )
        except (ValueError, SessionError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from exc
        typer.echo(
            f"wrote Minari dataset {dataset.spec.dataset_id}: {dataset.total_episodes} episodes, "
            f"{dataset.total_steps} steps, {int(info.takeover_steps)} takeover steps"
        )

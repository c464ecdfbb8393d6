"""``sage merge``: one ensemble from the world models of several refits of a policy (:mod:`core.merge`).

for seed in 0 1 2 3 4; do sage train ... --world-model-only --init POLICY --seed $seed --out runs/wm-$seed; done
sage merge runs/wm-0 runs/wm-1 runs/wm-2 runs/wm-3 runs/wm-4 --out runs/wm-bag
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def merge(
        runs: Annotated[
            list[str], typer.Argument(help="Run folders (or checkpoints) of world-model refits of one policy.")
        ],
        out: Annotated[Path, typer.Option(help="Folder for the merged run (must not hold a checkpoint yet).")],
        seed: Annotated[int, typer.Option(help="Seed of the draw of calibration states.")] = 0,
        checkpoint_dtype: Annotated[
            str, typer.Option(help="float32, or float16 to halve the file (committed policies).")
        ] = "float32",
    ) -> None:
        """Merge the world models of RUNS into one ensemble of all their members (the first run's policy), and set
        its κ and τ bounds on the states the runs calibrated on (their calibration.npz)."""
        import torch

        from core.merge import merge_runs

        torch.set_num_threads(1)
        try:
            result = merge_runs(runs, out, seed=seed, dtype=checkpoint_dtype)
        except (ValueError, FileNotFoundError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from exc
        low, high = result.tau_bounds
        typer.echo(
            f"merged {len(result.runs)} world models into {result.out}: {result.members} members; τ bounds "
            f"({low:.3f}, {high:.3f}) from {result.calibration_states} states ({result.familiar_states} familiar)"
        )

"""``python -m app.cli``: the ``sage`` command without its console script (e.g. from a git worktree)."""

from app.cli import main

main()

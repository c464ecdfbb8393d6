"""libsumo as a process-wide resource: a quiet import, one error type, and who owns the simulation.

libsumo runs ONE simulation per process: a second ``start()`` silently replaces the first, even with a label.
So the in-process :class:`~sims.sumo.env.SumoEnv` takes the simulation through :func:`start`, which closes
whatever ran before and records the new owner; an env whose simulation was taken over finds out through
:func:`owns` and raises a clear :class:`SumoError` instead of silently driving someone else's vehicles.
Parallel simulations are separate processes (:class:`~sims.sumo.process.SumoProcessEnv`).
"""

from __future__ import annotations

import contextlib
import io
import threading
from collections.abc import Sequence

with contextlib.redirect_stdout(io.StringIO()):
    # libsumo prints a pyarrow ABI warning on import when pyarrow's version differs from the one SUMO was built
    # against; only SUMO's parquet output would use it, and that output is never enabled here.
    import libsumo

TraCIException = libsumo.TraCIException
SUMO_ERRORS: tuple[type[Exception], ...] = (libsumo.TraCIException, libsumo.FatalTraCIError)
"""What libsumo raises: a refused command (TraCIException) or a simulation that is gone (FatalTraCIError)."""


class SumoError(RuntimeError):
    """A SUMO failure (bad input file, crashed or lost simulation) with a message that names the problem."""


_lock = threading.Lock()
_owner: object | None = None
_running = False


def start(owner: object, args: Sequence[str]) -> None:
    """Start a simulation for ``owner`` with SUMO command-line ``args`` (without the binary name).

    Whatever simulation ran in this process before is closed first. Raises :class:`SumoError` with SUMO's
    own message when SUMO refuses the input (missing or malformed network, route or option).
    """
    global _owner, _running
    with _lock:
        if _running:
            with contextlib.suppress(Exception):
                libsumo.close()
            _running = False
        _owner = owner
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                libsumo.start(["sumo", *args])
        except Exception as exc:  # TraCIException or FatalTraCIError, both carry SUMO's reason
            _owner = None
            with contextlib.suppress(Exception):
                libsumo.close()
            raise SumoError(f"SUMO could not start: {str(exc).strip()}") from exc
        _running = True


def close(owner: object) -> None:
    """Close the simulation if ``owner`` still owns it (closing twice, or after a takeover, does nothing)."""
    global _owner, _running
    with _lock:
        if _owner is owner:
            if _running:
                with contextlib.suppress(Exception):
                    libsumo.close()
            _running = False
            _owner = None


def owns(owner: object) -> bool:
    """True while ``owner`` holds the running simulation of this process."""
    return _running and _owner is owner

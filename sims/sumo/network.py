"""The composite network: its source XML, its compiled ``.net.xml`` and the netconvert call that links them.

The network is hand-made plain XML in ``sims/sumo/data`` (nodes, edges, connections, traffic-light programs)
compiled by netconvert from ``composite.netccfg``. The compiled ``composite.net.xml`` is committed, so a fresh
machine runs without compiling; ``python -m sims.sumo.network`` rebuilds it after the sources change.

The SUMO binaries come with the ``eclipse-sumo`` wheel (``sumo.SUMO_HOME/bin``); the pip packages do not set
``SUMO_HOME`` in the environment, so it is read from the ``sumo`` package itself.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

DATA_DIR = Path(__file__).resolve().parent / "data"
NETCCFG = DATA_DIR / "composite.netccfg"
NET_FILE = DATA_DIR / "composite.net.xml"
SOURCE_FILES = tuple(DATA_DIR / f"composite.{kind}.xml" for kind in ("nod", "edg", "con", "tll"))


class NetworkBuildError(RuntimeError):
    """netconvert failed or is missing; the message carries netconvert's own output."""


def sumo_home() -> Path:
    """Where the eclipse-sumo wheel keeps SUMO (binaries in ``bin/``, tools in ``tools/``)."""
    import sumo

    return Path(sumo.SUMO_HOME)


def sumo_binary(name: str) -> Path:
    """Path of a SUMO command-line tool (``netconvert``, ``sumo``, ``duarouter``), with a clear error if absent."""
    candidates = [sumo_home() / "bin" / name, Path(sys.executable).parent / name]
    which = shutil.which(name)
    if which:
        candidates.append(Path(which))
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return path
    raise NetworkBuildError(f"SUMO tool {name!r} not found (looked in {', '.join(str(c) for c in candidates)})")


def build_network(output: Path | None = None, config: Path = NETCCFG, timeout: float = 120.0) -> Path:
    """Compile the source XML named in ``config`` with netconvert and return the written ``.net.xml``.

    ``output`` defaults to the file named in the config (``composite.net.xml`` beside the sources). The network
    is written to a temporary file first and moved into place only when netconvert succeeded, so a failed
    build never leaves a broken network behind.
    """
    config = Path(config).resolve()
    if not config.is_file():
        raise NetworkBuildError(f"netconvert configuration not found: {config}")
    output = Path(output).resolve() if output is not None else NET_FILE
    output.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="sage-netconvert-") as tmp:
        partial = Path(tmp) / output.name
        cmd = [str(sumo_binary("netconvert")), "-c", str(config), "--output-file", str(partial)]
        # netconvert resolves the input files relative to the configuration file's folder
        proc = subprocess.run(cmd, cwd=config.parent, capture_output=True, text=True, timeout=timeout)
        if proc.returncode != 0 or not partial.is_file():
            detail = (proc.stderr or proc.stdout).strip()
            raise NetworkBuildError(f"netconvert failed on {config} (exit {proc.returncode}):\n{detail}")
        shutil.move(str(partial), output)
    return output


def network_is_current(net_file: Path = NET_FILE) -> bool:
    """True when the compiled network is newer than every source file (a hint; the tests compare content)."""
    if not net_file.is_file():
        return False
    built = net_file.stat().st_mtime
    return all(src.stat().st_mtime <= built for src in (*SOURCE_FILES, NETCCFG))


if __name__ == "__main__":
    print(f"wrote {build_network()}")

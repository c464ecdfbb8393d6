"""The container files are valid and serve what the README promises.

There is no Docker engine on the test machines, so the image is never built here; Debian's
``docker-compose`` (installed by ``scripts/setup.sh --browser``) validates the compose file and prints it
resolved, and the tests read that resolved form rather than the YAML text.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = shutil.which("docker-compose")
needs_compose = pytest.mark.skipif(
    COMPOSE is None, reason="docker-compose is not installed (scripts/setup.sh --browser installs Debian's)"
)


def compose(*args: str, file: Path = ROOT / "docker-compose.yml") -> subprocess.CompletedProcess[str]:
    assert COMPOSE is not None
    return subprocess.run(
        [COMPOSE, "-f", str(file), *args], cwd=file.parent, capture_output=True, text=True, timeout=60
    )


def resolved() -> dict[str, Any]:
    done = compose("config")
    assert done.returncode == 0, done.stderr
    return yaml.safe_load(done.stdout)


@needs_compose
def test_compose_file_is_valid() -> None:
    done = compose("config", "-q")
    assert done.returncode == 0, done.stderr


@needs_compose
def test_compose_validation_rejects_a_broken_file(tmp_path: Path) -> None:
    """The check above can fail: a misspelt service key is refused."""
    broken = tmp_path / "docker-compose.yml"
    broken.write_text((ROOT / "docker-compose.yml").read_text().replace("healthcheck:", "healthcheks:"))
    done = compose("config", "-q", file=broken)
    assert done.returncode != 0
    assert "healthcheks" in done.stderr


@needs_compose
def test_compose_serves_the_dashboard_from_the_pinned_image_on_loopback() -> None:
    service = resolved()["services"]["dashboard"]
    assert service["build"]["dockerfile"] == "Dockerfile"
    assert Path(service["build"]["context"]).resolve() == ROOT
    published = [str(p) for p in service["ports"]]
    assert published == ["127.0.0.1:8000:8000/tcp"], "the host side must stay on loopback"
    command = service["command"]
    assert command[:2] == ["sage", "serve"]
    sessions = command[command.index("--sessions") + 1]
    volumes = [str(v) for v in service["volumes"]]
    assert any(v.split(":")[1] == sessions and not v.startswith(("/", ".")) for v in volumes), (
        f"sessions ({sessions}) must live in a named volume, got {volumes}"
    )


@needs_compose
def test_healthcheck_asks_a_route_the_server_has() -> None:
    health = resolved()["services"]["dashboard"]["healthcheck"]
    probe = " ".join(health["test"])
    url = re.search(r"http://127\.0\.0\.1:8000(/[\w/]*)", probe)
    assert url is not None, probe
    routes = re.findall(r'@app\.get\("([^"]+)"', (ROOT / "app" / "server.py").read_text())
    assert url.group(1) in routes


def test_dockerfile_uses_the_setup_script_with_the_cpu_torch_index() -> None:
    """The image is set up by the same script as a fresh machine, torch from the CPU wheel index."""
    dockerfile = (ROOT / "Dockerfile").read_text()
    assert re.search(r"^FROM python:3\.11", dockerfile, re.M)
    assert "SAGE_TORCH_INDEX=https://download.pytorch.org/whl/cpu" in dockerfile
    assert re.search(r"^RUN bash scripts/setup\.sh", dockerfile, re.M)
    setup = (ROOT / "scripts" / "setup.sh").read_text()
    torch_line = setup.index('"torch==2.13.0"')
    assert "SAGE_TORCH_INDEX" in setup[setup.rfind("\n", 0, torch_line) : torch_line]
    assert torch_line < setup.index("-c requirements.lock"), "torch must be installed before the lock"
    ignored = (ROOT / ".dockerignore").read_text().split()
    assert ".venv" in ignored and "sessions/*" in ignored

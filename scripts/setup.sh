#!/usr/bin/env bash
# Idempotent set-up for a fresh machine: a virtual environment in .venv holding the pinned
# dependencies (torch 2.13.0 CPU first, so that nothing pulls a CUDA build). With --browser it also
# installs Debian's chromium for the browser tests and docker-compose, which the container test uses to
# validate docker-compose.yml. SAGE_TORCH_INDEX (the Dockerfile sets it) names the index that serves
# the CPU torch wheel where PyPI's default would be the CUDA build. A second run with nothing changed
# takes a second.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${SAGE_VENV:-.venv}

if [[ " $* " == *" --browser "* ]]; then
  missing=()
  command -v chromium >/dev/null 2>&1 || missing+=(chromium)
  command -v docker-compose >/dev/null 2>&1 || missing+=(docker-compose)
  if [ ${#missing[@]} -gt 0 ]; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    echo "setup: installing Debian's ${missing[*]} for the browser and container tests"
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -qq
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  fi
fi

[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
stamp="$VENV/.sage-setup"
want=$(cat pyproject.toml requirements.lock | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null || true)" != "$want" ]; then
  echo "setup: installing Python dependencies into $VENV (first time: a few minutes)"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q ${SAGE_TORCH_INDEX:+--index-url "$SAGE_TORCH_INDEX"} "torch==2.13.0"
  "$VENV/bin/python" -m pip install -q -c requirements.lock -e ".[dev,bench]"
  echo "$want" > "$stamp"
fi

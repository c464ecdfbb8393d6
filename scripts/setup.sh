#!/usr/bin/env bash
# Idempotent set-up for a fresh machine: a virtual environment in .venv holding the pinned
# dependencies (torch 2.13.0 CPU first, so that nothing pulls a CUDA build). With --browser it also
# installs Debian's chromium for the browser tests. A second run with nothing changed takes a second.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${SAGE_VENV:-.venv}

if [[ " $* " == *" --browser "* ]] && ! command -v chromium >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  echo "setup: installing Debian's chromium for the browser tests"
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi

[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
stamp="$VENV/.sage-setup"
want=$(cat pyproject.toml requirements.lock | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null || true)" != "$want" ]; then
  echo "setup: installing Python dependencies into $VENV (first time: a few minutes)"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q "torch==2.13.0"
  "$VENV/bin/python" -m pip install -q -c requirements.lock -e ".[dev,bench]"
  echo "$want" > "$stamp"
fi

# The two commands a fresh machine needs (see README): `make serve` and `make test`.
PY := .venv/bin/python

.PHONY: setup serve test test-all lint bench

setup:
	bash scripts/setup.sh

serve: setup
	.venv/bin/sage serve

test:
	bash scripts/setup.sh --browser
	$(PY) -m ruff check .
	$(PY) -m pytest -q

test-all:  # includes the slow learning runs
	bash scripts/setup.sh --browser
	$(PY) -m pytest -q -m ""

lint:
	$(PY) -m ruff check . && $(PY) -m ruff format --check .

bench: setup
	for f in bench/bench_*.py; do $(PY) $$f || exit 1; done

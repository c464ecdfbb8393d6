# The two commands a fresh machine needs (see README): `make serve` and `make test`.
PY := .venv/bin/python

.PHONY: setup serve test test-all lint bench screenshot

setup:
	bash scripts/setup.sh

serve: setup
	.venv/bin/sage serve

test:
	bash scripts/setup.sh --browser
	$(PY) -m ruff check .
	$(PY) -m mypy  # the packages [tool.mypy] names in pyproject.toml
	$(PY) -m pytest -q -n auto --maxprocesses 4  # pytest-xdist: the suite on up to four cores

test-all:  # includes the slow learning runs
	bash scripts/setup.sh --browser
	$(PY) -m pytest -q -n auto --maxprocesses 4 -m ""

lint:
	$(PY) -m ruff check . && $(PY) -m ruff format --check . && $(PY) -m mypy

bench: setup  # speed benchmarks; the investigations are experiments/ (python -m experiments.NAME, one by one)
	for f in bench/bench_*.py; do $(PY) $$f || exit 1; done

screenshot:  # refresh docs/dashboard.png (the README's picture) from a real browser session
	bash scripts/setup.sh --browser
	SAGE_UPDATE_SCREENSHOT=1 $(PY) -m pytest -q tests/app/test_dashboard_browser.py -k "readme_screenshot or layout_fits"

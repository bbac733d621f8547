# printhost: every target is one line; no hidden logic.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
MANAGE := $(BIN)/python manage.py

.PHONY: install lint format test test-fast check migrate run demo printer sim bench clean

$(BIN)/python:
	$(PY) -m venv $(VENV)

install: $(BIN)/python
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements-dev.txt

lint: install
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

format: install
	$(BIN)/ruff check --fix . && $(BIN)/ruff format .

test: install
	$(BIN)/python -m pytest -n 3 --dist worksteal --durations=20

test-fast: install
	$(BIN)/python -m pytest tests/protocol tests/streaming

check: lint test

migrate: install
	$(MANAGE) migrate --noinput

demo: migrate
	$(MANAGE) setup_demo

run: demo
	$(MANAGE) runhost

printer: migrate
	$(MANAGE) run_printer $(SLUG)

sim: install
	$(BIN)/python -m printers.simulator marlin --link ./printer0 --baud 250000

bench: install
	$(BIN)/python -m bench.streaming && $(BIN)/python -m bench.loop_cost && $(BIN)/python -m bench.analysis && $(BIN)/python -m bench.eta && $(BIN)/python -m bench.farm

clean:
	rm -rf $(VENV) var .pytest_cache .ruff_cache .hypothesis bench-results.json bench-soak.json bench-analysis.json bench-eta.json bench-farm.json

# Two commands for a fresh machine with Python 3.11:
#   make demo   - install into .venv, then race the stack against the simulator (telemetry recorded)
#   make test   - install into .venv (with test tools), lint with ruff, run the test suite
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin

.PHONY: demo test install install-dev lint bench clean

$(BIN)/python:
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) on PATH (or: make PYTHON=python3 ...)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

install: $(BIN)/python
	$(BIN)/pip install --quiet -e .

install-dev: $(BIN)/python
	$(BIN)/pip install --quiet -e '.[dev]'

lint: install-dev
	$(BIN)/ruff check .

test: install-dev lint
	$(BIN)/python -m pytest -q

demo: install
	$(BIN)/racestack demo

bench: install
	$(BIN)/python -m benchmarks.solve_time

clean:
	rm -rf $(VENV) build *.egg-info

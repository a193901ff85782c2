# Two commands for a fresh machine with Python 3.11:
#   make demo   - install into .venv, then race the stack against the simulator (telemetry recorded)
#   make test   - install into .venv (with test tools and every extra), lint, run the test suite
#                 (first installing Debian's postgresql when it is missing and apt is there, for
#                 the tuner's PostgreSQL study test; without it that test skips)
# `make install` is the stack alone (every process service and `racestack up`/`demo`);
# `make install-tools` adds the [tools] extra (figures, tune, track --from-map) and [ros2].
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin

.PHONY: demo test install install-tools install-dev lint bench clean postgres

$(BIN)/python:
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) on PATH (or: make PYTHON=python3 ...)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

install: $(BIN)/python
	$(BIN)/pip install --quiet -e .

install-tools: $(BIN)/python
	$(BIN)/pip install --quiet -e '.[tools,ros2]'

install-dev: $(BIN)/python
	$(BIN)/pip install --quiet -e '.[dev,tools,ros2]'

lint: install-dev
	$(BIN)/ruff check .

# The machine's PostgreSQL server binaries for tests/tools/tune (a throwaway server per test
# module): Debian's postgresql package, installed as root with apt when missing; never fails
# (the test skips, saying why, when PostgreSQL cannot be had).
postgres:
	@if ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; then :; \
	elif command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
		echo "installing Debian's postgresql (for the tuner's PostgreSQL test) ..."; \
		{ apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
			--no-install-recommends postgresql; } >/dev/null 2>&1 \
			|| echo "postgresql could not be installed; the PostgreSQL test will skip"; \
	else echo "no PostgreSQL and no apt-get as root; the PostgreSQL test will skip"; fi

test: postgres install-dev lint
	$(BIN)/python -m pytest -q

demo: install
	$(BIN)/racestack demo

bench: install
	$(BIN)/python -m benchmarks.solve_time

clean:
	rm -rf $(VENV) build *.egg-info

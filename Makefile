# qkf: two commands set up a fresh machine and do the work.
#   make bench   create .venv, install, run the main benchmark (results/paper/)
#   make test    create .venv, install, run the whole test suite (spread over the cores)
#   make test-fast   the same without the tests marked slow: the check to run while working
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# torch first and pinned: the CPU wheel on disk; any other spec pulls the CUDA stack.
TORCH := torch==2.13.0

.PHONY: install bench test test-fast lint typecheck speed clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet $(TORCH)
	$(BIN)/python -m pip install --quiet -e '.[dev,ray]'
	touch $(STAMP)

install: $(STAMP)

bench: $(STAMP)
	$(BIN)/qkf bench paper --out results/paper --overwrite

# One numba thread per test worker: -n auto already puts a worker on every core, and numba's
# own thread pool in each worker on top of that oversubscribes the cores (the parallel filter
# kernel then waits on its threads: the suite took 10 min instead of 6 on 2 cores).
TEST_ENV := NUMBA_NUM_THREADS=1

test: $(STAMP)
	$(TEST_ENV) $(BIN)/python -m pytest -q -n auto

# Long Monte Carlo statistics, training and wheel builds are marked slow (pyproject.toml,
# [tool.pytest.ini_options]); `make test` and CI (.ci/run) still run them.
test-fast: $(STAMP)
	$(TEST_ENV) $(BIN)/python -m pytest -q -n auto -m "not slow"

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy

speed: $(STAMP)
	$(BIN)/python benchmarks/filter_speed.py

clean:
	rm -rf $(VENV) results .pytest_cache .mypy_cache .ruff_cache

# qkf: two commands set up a fresh machine and do the work.
#   make bench   create .venv, install, run the main benchmark (results/paper/)
#   make test    create .venv, install, run the whole test suite (spread over the cores)
#   make test-fast   the same without the tests marked slow: the check to run while working
#   make test-portable   test-fast as if on another CPU (generic numba code, numpy without its
#                    AVX kernels): run it before changing any tolerance
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# torch first and pinned: the CPU wheel on disk; any other spec pulls the CUDA stack.
TORCH := torch==2.13.0

.PHONY: install bench test test-fast test-portable lint typecheck speed clean

# Python keeps the bytecode of the modules it imports (__pycache__/*.pyc) unless
# PYTHONDONTWRITEBYTECODE is set, as it is on some machines. The install leaves the compiling
# to the first import (--no-compile below); with the variable set, every process compiled
# torch, numpy, scipy, numba and qkf from source again: 10 s to import that stack, 3.8 s from
# the bytecode. The suite starts dozens of processes (workers, commands, pools, Ray), so the
# commands here write it: an empty value is "not set".
PY_ENV := PYTHONDONTWRITEBYTECODE=

# --no-compile: pip would byte-compile every module of every package (torch alone: 38 s
# instead of 12 s on 2 cores); Python compiles the few that are imported, once, on first use.
PIP := $(BIN)/python -m pip install --quiet --no-compile

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(PIP) --upgrade pip
	$(PIP) $(TORCH)
	$(PIP) -e '.[dev,ray]'
	touch $(STAMP)

install: $(STAMP)

bench: $(STAMP)
	$(PY_ENV) $(BIN)/qkf bench paper --out results/paper --overwrite

# One numba thread per test worker: -n auto already puts a worker on every core, and numba's
# own thread pool in each worker on top of that oversubscribes the cores (the parallel filter
# kernel then waits on its threads: the suite took 10 min instead of 6 on 2 cores).
TEST_ENV := NUMBA_NUM_THREADS=1 $(PY_ENV)

test: $(STAMP)
	$(TEST_ENV) $(BIN)/python -m pytest -q -n auto

# Long Monte Carlo statistics, training and wheel builds are marked slow (pyproject.toml,
# [tool.pytest.ini_options]); `make test` and CI (.ci/run) still run them.
test-fast: $(STAMP)
	$(TEST_ENV) $(BIN)/python -m pytest -q -n auto -m "not slow"

# test-fast as close to another x86-64 CPU as this one allows, for the pins of computed floats
# (a test must pass on every machine): numba compiles for a generic CPU (its cache keeps that
# code apart from the native one), and numpy's SIMD kernels chosen at run time (AVX2, AVX-512)
# are switched off. numpy refuses to switch off its baseline, so the list is read from numpy:
# the dispatched features this CPU has. OpenBLAS keeps its kernel for this CPU.
NPY_DISPATCHED := import numpy as np; m = np._core._multiarray_umath; \
	print(",".join(f for f in m.__cpu_dispatch__ if m.__cpu_features__.get(f)))
test-portable: $(STAMP)
	$(TEST_ENV) NUMBA_CPU_NAME=generic \
	NPY_DISABLE_CPU_FEATURES="$$($(BIN)/python -c '$(NPY_DISPATCHED)')" \
	$(BIN)/python -m pytest -q -n auto -m "not slow"

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy

speed: $(STAMP)
	$(BIN)/python benchmarks/filter_speed.py

clean:
	rm -rf $(VENV) results .pytest_cache .mypy_cache .ruff_cache

# Two commands do everything on a fresh machine (see README.md):
#   make demo   process every run in data_samples/ into ./calib-archive, write the reports,
#               fit and export a thermal model, show a trend and repeatability
#   make test   the whole test suite (installs PostgreSQL and poppler-utils if the machine lacks them)
#   make test-fast  the tests to run before every commit (every package, without the slow tiers)
#   make bench  every benchmark of benchmarks/
# Every target works in one environment, $(VENV): each installs the extras it needs into it,
# once, and records them (a stamp file per set, $(VENV)/.installed-EXTRAS), so `make demo`
# then `make test-fast` (or the other way round) installs only what is missing.
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.installed
export DO_NOT_TRACK = 1
export PREFECT_SERVER_ANALYTICS_ENABLED = false
# Byte code is cached: with PYTHONDONTWRITEBYTECODE set, every test run would compile the
# project's modules and pytest would rewrite the asserts of every test module again
# (about half the CPU of collecting the tests).
unexport PYTHONDONTWRITEBYTECODE

.PHONY: demo test test-fast bench venv system-packages clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip

# calib itself ("base") or calib with a set of extras of pyproject.toml, named with "-"
# between them (test-dask: ".[test,dask]"); installing extras installs calib too, so it
# records both.
comma := ,
$(STAMP)-%: pyproject.toml | $(BIN)/python
	@echo "== installing calib$(if $(filter base,$*),, with the extras $(subst -,$(comma),$*)) into $(VENV) =="
	@start=$$(date +%s); \
	$(BIN)/pip install -q -e ".$(if $(filter base,$*),,[$(subst -,$(comma),$*)])" && \
	echo "   installed in $$(( $$(date +%s) - start )) s"
	@touch $(sort $@ $(STAMP)-base)

# What the tests and benchmarks need: pytest, pytest-xdist, ruff, ... and Dask.
TEST_EXTRAS = $(STAMP)-test-dask

venv: $(TEST_EXTRAS)

# The whole product on the samples: every run processed and reported, the thermal campaign
# fitted and exported for PX4 and ArduPilot, the quarterly unit's trend and repeatability
# (scripts/demo.sh, which says each step and how long it took). It needs calib alone.
DEMO_OUT = demo-output

demo: $(STAMP)-base
	@BIN=$(BIN) DEMO_OUT=$(DEMO_OUT) bash scripts/demo.sh

system-packages:
	bash scripts/ensure_system_packages.sh

LINTED = calib_core storage pipelines calib_testing tests benchmarks scripts

test: $(TEST_EXTRAS) system-packages
	$(BIN)/ruff check $(LINTED)
	$(BIN)/ruff format --check $(LINTED)
	$(BIN)/python -m pytest -q

# The tiers `make test-fast` leaves out (pyproject.toml; tests/conftest.py marks the tests
# using PostgreSQL or the Prefect server by their fixtures), on both cores (pytest-xdist),
# a module's tests on one of them (--dist loadscope: a module's fixtures, often an archive
# built by the real pipeline, are built once, not once in each worker).
FAST = not slow and not postgres and not browser and not e2e

test-fast: $(TEST_EXTRAS) system-packages
	$(BIN)/ruff check $(LINTED)
	$(BIN)/ruff format --check $(LINTED)
	$(BIN)/python -m pytest -q -m "$(FAST)" -n 2 --dist loadscope

bench: $(TEST_EXTRAS)
	for b in benchmarks/*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) calib-archive $(DEMO_OUT) .pytest_cache

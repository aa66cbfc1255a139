# Two commands do everything on a fresh machine (see README.md):
#   make demo   process every run in data_samples/ into ./calib-archive and write the reports
#   make test   the whole test suite (installs PostgreSQL and poppler-utils if the machine lacks them)
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
export DO_NOT_TRACK = 1
export PREFECT_SERVER_ANALYTICS_ENABLED = false

.PHONY: demo test bench venv system-packages clean

$(BIN)/calib: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[test,dask]"
	touch $@

venv: $(BIN)/calib

demo: venv
	$(BIN)/calib process data_samples --reports

system-packages:
	bash scripts/ensure_system_packages.sh

test: venv system-packages
	$(BIN)/ruff check calib_core storage pipelines tests benchmarks
	$(BIN)/python -m pytest -q

bench: venv
	for b in benchmarks/*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) calib-archive .pytest_cache

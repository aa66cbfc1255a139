# Two commands do everything on a fresh machine (see README.md):
#   make demo   process every run in data_samples/ into ./calib-archive, write the reports,
#               fit and export a thermal model, show a trend and repeatability
#   make test   the whole test suite (installs PostgreSQL and poppler-utils if the machine lacks them)
#   make test-fast  the tests to run before every commit (every package, without the slow tiers)
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
export DO_NOT_TRACK = 1
export PREFECT_SERVER_ANALYTICS_ENABLED = false

.PHONY: demo test test-fast bench venv system-packages clean

$(BIN)/calib: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[test,dask]"
	touch $@

venv: $(BIN)/calib

# The whole product on the samples: every run processed and reported, the thermal campaign
# fitted and exported for PX4 and ArduPilot, the quarterly unit's trend and repeatability.
# It installs calib alone (not the test and dask extras, which it does not run).
DEMO_OUT = demo-output
$(VENV)/.demo-installed: pyproject.toml
	@echo "== make demo: installing calib into $(VENV) (without the test and dask extras) =="
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e .
	touch $@

demo: $(VENV)/.demo-installed
	@bash scripts/ensure_system_packages.sh --pdf
	@echo "== 1/5 processing every run of data_samples/ into ./calib-archive (certificates issued) =="
	$(BIN)/calib process data_samples --reports
	@echo "== 2/5 fitting the thermal model of the campaign IMU-T-0007 =="
	$(BIN)/calib thermal fit IMU-T-0007
	mkdir -p $(DEMO_OUT)
	@echo "== 3/5 exporting it for PX4 and ArduPilot into $(DEMO_OUT)/ =="
	@echo "   (PX4 needs the sensor's device id: the CSV samples record none, 1310988 stands for the vehicle's CAL_ACC0_ID)"
	$(BIN)/calib thermal export IMU-T-0007 $(DEMO_OUT)/IMU-T-0007_px4.params --format px4 --device-id 1310988
	$(BIN)/calib thermal export IMU-T-0007 $(DEMO_OUT)/IMU-T-0007_ardupilot.parm --format ardupilot
	@echo "== 4/5 the trend of IMU-R-0003's acc.bias.z (plot into $(DEMO_OUT)/) =="
	$(BIN)/calib trend IMU-R-0003 acc.bias.z --plot $(DEMO_OUT)/IMU-R-0003_acc.bias.z_trend.png
	@echo "== 5/5 the repeatability of IMU-R-0003 (its acc.bias.z drifts on purpose: it fails) =="
	@$(BIN)/calib repeatability IMU-R-0003 || echo "(calib repeatability exits 1 here: the drift the sample was made with)"
	@echo
	@echo "Open: calib-archive/runs/<serial>/<date>/<run>/ (protocols, HTML and PDF certificates);"
	@echo "      $(DEMO_OUT)/ (PX4 and ArduPilot parameter files, the trend plot)."
	@echo "Try:  $(BIN)/calib history IMU-R-0003"
	@echo "      $(BIN)/calib show <run id from the table above, or its first 4+ characters>"
	@echo "      $(BIN)/calib query latest MPU0001"
	@echo "      $(BIN)/calib thermal show IMU-T-0007"
	@echo "      $(BIN)/calib export <run id> --format ardupilot"
	@echo "      $(BIN)/calib serve        (browse the archive at http://127.0.0.1:8000/)"
	@echo "      $(BIN)/calib --help       (every command, grouped by task)"

system-packages:
	bash scripts/ensure_system_packages.sh

LINTED = calib_core storage pipelines calib_testing tests benchmarks scripts

test: venv system-packages
	$(BIN)/ruff check $(LINTED)
	$(BIN)/ruff format --check $(LINTED)
	$(BIN)/python -m pytest -q

# The tiers `make test-fast` leaves out (pyproject.toml; tests/conftest.py marks the tests
# using PostgreSQL or the Prefect server by their fixtures).
FAST = not slow and not postgres and not browser and not e2e

test-fast: venv system-packages
	$(BIN)/ruff check $(LINTED)
	$(BIN)/ruff format --check $(LINTED)
	$(BIN)/python -m pytest -q -m "$(FAST)"

bench: venv
	for b in benchmarks/*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) calib-archive $(DEMO_OUT) .pytest_cache

# scart-bench: `make run` sets up and runs the benchmark, `make test` sets up and runs the tests.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# the example detector plugin, installed for the tests only (into its own folder, on PYTHONPATH for
# `make test`): `make run`'s table lists the built-ins and the plugins a user installed, not this one
PLUGIN := $(VENV)/example-plugin

# Telemanom's optional tensorflow backend (the extra `scart-bench[tensorflow]`), installed for the tests
TF_STAMP := $(VENV)/.installed-tf

.PHONY: setup setup-tf run test lint clean

setup: $(STAMP)

$(STAMP): pyproject.toml Makefile
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# torch first, the CPU build: anything else would pull a CUDA torch of several GB
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e '.[dev]'
	# deepod pins an old torch in its metadata; its real needs are installed above
	$(BIN)/pip install --quiet --no-deps deepod==0.4.1
	# TSB-AD's reference metrics for the cross-check test; its pins would downgrade numpy
	$(BIN)/pip install --quiet --no-deps tsb-ad==1.5
	# an example plugin installed into the venv by an earlier Makefile would show in `make run`'s table
	$(BIN)/pip uninstall --quiet -y scart-bench-example-detector 2>/dev/null || true
	# compile the generator's numba kernels once into the package's on-disk cache (about 1 min on 2
	# cores): two normal and one attacked flight, thrown away; the first `make run` then starts warm
	$(BIN)/scart-bench generate --profile quick --flights 2 --scenarios data/scenarios/gps_spoof.toml \
		--out $(VENV)/warmup --overwrite > /dev/null
	rm -rf $(VENV)/warmup $(VENV)/.warmup.*
	touch $(STAMP)

# optional, not part of `make setup`: tensorflow-cpu for Telemanom(backend="tensorflow") and its test
# (tests/test_telemanom_tensorflow.py, skipped without it); ~300 MB of wheels, ~1.4 GB installed, numpy and
# torch left as they are
setup-tf: $(TF_STAMP)

$(TF_STAMP): $(STAMP)
	$(BIN)/pip install --quiet -e '.[tensorflow]'
	touch $@

$(PLUGIN)/.installed: $(STAMP) examples/custom_detector/pyproject.toml $(wildcard examples/custom_detector/scart_example_detector/*.py)
	rm -rf $(PLUGIN)
	# the example detector plugin, installed with pip as a user would (its tests check it is discovered)
	$(BIN)/pip install --quiet --no-deps --target $(PLUGIN) examples/custom_detector
	rm -rf examples/custom_detector/build
	touch $@

run: setup
	$(BIN)/scart-bench run --detectors all --jobs 2

# the suite in TEST_WORKERS processes (pytest-xdist), a test file per process so that its module fixtures
# (a generated dataset, a roscore) are made once: 13.6 min instead of 24 on 2 cores
TEST_WORKERS ?= 2

test: setup setup-tf $(PLUGIN)/.installed
	PYTHONPATH=$(abspath $(PLUGIN)) $(BIN)/pytest -q -n $(TEST_WORKERS) --dist loadfile --durations=30

lint: setup
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) runs data/datasets

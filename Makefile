# servowatch: every target bootstraps a local .venv from the project's own files.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
# numba caches its compiled kernels next to the sources; a kernel that inlines code from
# another module is not recompiled when only that module changes, so clear and rebuild
# the caches whenever a kernel source changes.
KERNEL_SRC := $(wildcard models/*.py service/monitor/*.py service/compat/*.py) service/wire/kernels.py $(wildcard service/log/codec*.py)
KERNELS := $(VENV)/.kernels-stamp
# the tests and benchmarks use every kernel (the simplified valves' bench, the WH monitor too)
KERNELS_ALL := $(VENV)/.kernels-all-stamp

.PHONY: demo fleet-page test test-fast lint format bench evaluate clean

# Python byte-compiles the modules a command imports on their first import (--no-compile:
# not every module of every package at install time, half the install's time); the targets
# here let it write those caches even where the environment says not to, or every process
# would compile its imports again
unexport PYTHONDONTWRITEBYTECODE
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --no-compile --upgrade pip
	$(PY) -m pip install -q --no-compile -e '.[dev]'
	touch $(STAMP)

$(KERNELS): $(STAMP) $(KERNEL_SRC)
	find models service \( -name '*.nbi' -o -name '*.nbc' \) -delete
	$(VENV)/bin/servowatch warmup
	touch $(KERNELS)

$(KERNELS_ALL): $(KERNELS)
	$(VENV)/bin/servowatch warmup --all
	touch $(KERNELS_ALL)

demo: $(KERNELS)
	$(VENV)/bin/servowatch demo

# the fleet page on a simulated fleet: 12 units with hidden wear laws through the real monitor
# (servowatch fleet-sim), served read only on http://127.0.0.1:8080/ until Ctrl-C
FLEET_DEMO ?= servowatch-data/fleet-demo.sqlite
fleet-page: $(KERNELS)
	test -e $(FLEET_DEMO) || $(VENV)/bin/servowatch fleet-sim --actuators 12 --flights 5 --seed 3 --store $(FLEET_DEMO) --truth servowatch-data/fleet-demo-truth.json
	$(VENV)/bin/servowatch web --store $(FLEET_DEMO) --plain-logs

test: $(KERNELS_ALL)
	$(PY) -m pytest -q

test-fast: $(KERNELS_ALL)
	$(PY) -m pytest -q -m "not slow"

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

format: $(STAMP)
	$(VENV)/bin/ruff format .
	$(VENV)/bin/ruff check --fix .

bench: $(KERNELS_ALL)
	$(PY) bench/models.py
	$(PY) bench/estimation.py
	$(PY) bench/service.py

# the monitor against the HF bench: process models over noise seeds, the duty-cycle suite
evaluate: $(KERNELS)
	$(PY) -m evaluation.seeds --models C5,WH --seeds 8 --workers 2
	$(PY) -m evaluation.suite --seeds 1-7 --workers 2

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info

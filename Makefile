# BeAMS for ROS 2: the user-facing commands. See README.md.
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
ROOT := $(abspath .)
VENV := $(ROOT)/.venv
BUILD_BASE ?= $(ROOT)/build
INSTALL_BASE ?= $(ROOT)/install
export BEAMS_INSTALL_BASE := $(INSTALL_BASE)
ROS_ENV := source $(ROOT)/scripts/ros_env.sh &&
PACKAGE_SOURCES := $(shell find src compat -type f -not -path '*/__pycache__/*' -not -path '*/test/*' 2>/dev/null)
PYTEST_ARGS ?=

.PHONY: setup build test test-fast demo bench lint clean

## setup: create .venv with ROS 2 Jazzy and the libraries (once; again when requirements change)
$(VENV)/.installed: requirements.txt requirements-nonros.txt constraints.txt scripts/bootstrap.sh scripts/fix_wheel_paths.py
	bash scripts/bootstrap.sh

setup: $(VENV)/.installed

## build: colcon build of every package (again only when a package file changed); the compat/ packages
## the ROS environment lacks (tf2_msgs from the PyPI wheels) are built too
$(INSTALL_BASE)/.built: $(VENV)/.installed $(PACKAGE_SOURCES) colcon.meta scripts/compat_packages.sh
	$(ROS_ENV) colcon --log-base $(BUILD_BASE)/log build --build-base $(BUILD_BASE) --install-base $(INSTALL_BASE) \
	    --base-paths src $$(scripts/compat_packages.sh) \
	    --metas colcon.meta --event-handlers console_direct- console_cohesion- summary+ status-
	touch $@

build: $(INSTALL_BASE)/.built

## test: the linters (ruff check, ruff format --check), then every test: the tiers without DDS (unit,
## scenario, thesis, static), then the DDS tier with DDS_WORKERS pytest-xdist workers side by side (its
## tests mostly wait; each claims a ROS_DOMAIN_ID of its own); exit 0 only when all pass. A part with no
## test in one of the two runs (exit status 5) is not an error: PYTEST_ARGS="src/beams_ekf -x"
DDS_WORKERS ?= 3
DDS_PARALLEL := $(if $(filter-out 0 1,$(DDS_WORKERS)),-n $(DDS_WORKERS) --dist loadfile)
test: build lint
	$(ROS_ENV) python -m pytest -m "not dds" $(PYTEST_ARGS) || [ $$? -eq 5 ]
	$(ROS_ENV) python -m pytest -m dds $(DDS_PARALLEL) $(PYTEST_ARGS) || [ $$? -eq 5 ]

## test-fast: the linters and every test but the DDS tier (about 2 minutes)
test-fast: build lint
	$(ROS_ENV) python -m pytest -m "not dds" $(PYTEST_ARGS)

## demo: the simulated robot, the BeAMS sensor, ToTal and the EKF on a Eurobot match
DEMO_ARGS ?=
demo: build
	$(ROS_ENV) python -m beams_bringup.demo $(DEMO_ARGS)

## bench: every benchmark under bench/, one table (the one BENCHMARKS.md records)
BENCH_ARGS ?=
bench: build
	$(ROS_ENV) python bench/run_all.py $(BENCH_ARGS)

## lint: ruff check and ruff format --check (a difference fails, as navigation2's linters fail its tests)
LINT_PATHS := src test bench scripts compat conftest.py
lint: $(VENV)/.installed
	$(VENV)/bin/ruff check $(LINT_PATHS)
	$(VENV)/bin/ruff format --check $(LINT_PATHS)

clean:
	rm -rf $(BUILD_BASE) $(INSTALL_BASE) log

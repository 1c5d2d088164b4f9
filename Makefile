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

.PHONY: setup build test demo bench lint clean

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

## test: the linters (ruff check, ruff format --check), then every test (unit, thesis figures, DDS
## integration); exit 0 only when all pass
test: build lint
	$(ROS_ENV) python -m pytest $(PYTEST_ARGS)

## demo: the simulated robot, the BeAMS sensor, ToTal and the EKF on a Eurobot match
DEMO_ARGS ?=
demo: build
	$(ROS_ENV) python -m beams_bringup.demo $(DEMO_ARGS)

## bench: every benchmark under bench/, one table (the one BENCHMARKS.md records)
BENCH_ARGS ?=
bench: build
	$(ROS_ENV) python bench/run_all.py $(BENCH_ARGS)

## lint: ruff check and ruff format --check (a difference fails, as navigation2's linters fail its tests)
LINT_PATHS := src test bench scripts compat
lint: $(VENV)/.installed
	$(VENV)/bin/ruff check $(LINT_PATHS)
	$(VENV)/bin/ruff format --check $(LINT_PATHS)

clean:
	rm -rf $(BUILD_BASE) $(INSTALL_BASE) log

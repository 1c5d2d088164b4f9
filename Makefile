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

.PHONY: setup build test test-fast demo bench lint clean firmware hil hil-if-possible

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
	@# byte-compiled once here: a node's (re)start then reads its modules instead of compiling them (0.3 s
	@# of CPU for ekf_node), also where PYTHONDONTWRITEBYTECODE keeps Python from caching them
	$(ROS_ENV) python -m compileall -q $(INSTALL_BASE) > /dev/null
	touch $@

build: $(INSTALL_BASE)/.built

## firmware: the microcontrollers' images with avr-gcc, warnings as errors: firmware/build/turret.elf and
## .hex (firmware/turret), and firmware/beacon when it has a Makefile (docs/firmware.md)
firmware:
	$(MAKE) -C firmware

## hil: the firmware and the simavr harness of the hardware-in-the-loop test (test/dds/test_firmware_hil.py)
HIL_HARNESS := $(BUILD_BASE)/hil/turret_hil
export BEAMS_HIL_HARNESS := $(HIL_HARNESS)
$(HIL_HARNESS): test/hil/turret_hil.c
	@mkdir -p $(@D)
	$(CC) -O2 -Wall -Wextra -Werror -I/usr/include/simavr -o $@ $< -lsimavr

hil: firmware $(HIL_HARNESS)

# `make test` builds them where the AVR toolchain and libsimavr are installed (scripts/bootstrap.sh does,
# as root); elsewhere it says why and the HIL tests skip with that reason
hil-if-possible:
	@if command -v avr-gcc >/dev/null 2>&1 && [ -f /usr/include/simavr/sim_avr.h ]; then \
	    $(MAKE) --no-print-directory hil; \
	else \
	    echo "make: avr-gcc or libsimavr-dev missing (scripts/bootstrap.sh installs them as root): the firmware HIL tests will skip"; \
	fi

## test: the linters (ruff check, ruff format --check), the firmware and its harness (when the AVR tools
## are installed), then every test: the tiers without DDS (unit, scenario with the firmware HIL, thesis,
## static) on FAST_WORKERS pytest-xdist workers, then the DDS tier with DDS_WORKERS workers side by side
## (its tests mostly wait; each claims a ROS_DOMAIN_ID of its own), its `alone` tests last; exit 0 only
## when all pass. A part with no test in one of the
## two runs (exit status 5) is not an error: PYTEST_ARGS="src/beams_ekf -x"
# Whole files per worker, in collection order: conftest.py puts the longest files first (FILE_SECONDS), so
# the workers finish together (xdist's own reordering, by number of tests, is turned off)
FAST_WORKERS ?= 2
FAST_PARALLEL := $(if $(filter-out 0 1,$(FAST_WORKERS)),-n $(FAST_WORKERS) --dist loadfile --no-loadscope-reorder)
DDS_WORKERS ?= 3
DDS_PARALLEL := $(if $(filter-out 0 1,$(DDS_WORKERS)),-n $(DDS_WORKERS) --dist loadfile --no-loadscope-reorder)
# Every DDS test passes the first time: a rerun hides a race or a node's defect that users meet, so none is
# made unless asked for while diagnosing one (`make test DDS_RERUNS=2`; -raR lists the reruns and failures
# in the summary). The tests marked `alone` (the fault campaign, the respawn timing, the EKF over the
# real-time firmware emulation: the whole suite on the two cores, timed) run after the others, one at a time.
DDS_RERUNS ?= 0
# Without PYTEST_ARGS each run collects only its tier's folders: every pytest-xdist worker collects what its
# run is given, and the whole suite's collection took 13 s of CPU against 4 s for test/dds alone.
FAST_PATHS := $(or $(PYTEST_ARGS),--ignore=test/dds)
DDS_PATHS := $(or $(PYTEST_ARGS),test/dds)
test: build lint hil-if-possible
	$(ROS_ENV) python -m pytest -m "not dds" $(FAST_PARALLEL) $(FAST_PATHS) || [ $$? -eq 5 ]
	$(ROS_ENV) python -m pytest -m "dds and not alone" $(DDS_PARALLEL) --reruns $(DDS_RERUNS) -raR $(DDS_PATHS) || [ $$? -eq 5 ]
	$(ROS_ENV) python -m pytest -m "dds and alone" --reruns $(DDS_RERUNS) -raR $(DDS_PATHS) || [ $$? -eq 5 ]

## test-fast: the linters, the firmware harness (when possible) and every test but the DDS tier, on
## FAST_WORKERS workers (FAST_WORKERS=1: one process)
test-fast: build lint hil-if-possible
	$(ROS_ENV) python -m pytest -m "not dds" $(FAST_PARALLEL) $(FAST_PATHS)

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
	rm -rf $(BUILD_BASE) $(INSTALL_BASE) log firmware/build

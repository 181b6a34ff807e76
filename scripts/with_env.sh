#!/usr/bin/env bash
# Runs a command inside the project's environment: venv, built ros_ws, DDS on loopback unless the caller chose
# otherwise (ROS_AUTOMATIC_DISCOVERY_RANGE, ROS_STATIC_PEERS and ROS_DOMAIN_ID are kept when set).
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${SOFTBLOCK_VENV:-$repo/.venv}"
source "$venv/bin/activate"
export AMENT_PREFIX_PATH="$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
set +u
source "$repo/ros_ws/install/setup.bash"
set -u
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# Unset, a domain of 1-9 taken from the user id: every terminal of one user on this machine meets in it (a stack
# in one, run_sequence in another), and it lies apart from the test suite's (10-99 by default, tests/ros_domains.py),
# so a stack started by hand never reaches a running suite.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( $(id -u) % 9 + 1 ))}"
export PYTHONUNBUFFERED=1
exec "$@"

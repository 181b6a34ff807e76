#!/usr/bin/env bash
# One idempotent set-up step: venv with pinned dependencies, the wheels' CMake path fix,
# the repo's core packages (editable) and the ROS 2 workspace built with colcon.
# A second run with nothing changed returns in a couple of seconds.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${SOFTBLOCK_VENV:-$repo/.venv}"
python="${PYTHON:-python3}"
cd "$repo"

step() { printf '[setup] %s\n' "$*" >&2; }

fingerprint() { cat "$@" 2>/dev/null | sha256sum | cut -c1-16; }

# 1. venv + pinned dependencies
deps_hash="$(fingerprint requirements.txt constraints.txt pyproject.toml)"
if [[ ! -x "$venv/bin/python" ]]; then
    step "creating venv at $venv"
    "$python" -m venv "$venv"
fi
if [[ "$(cat "$venv/.deps-stamp" 2>/dev/null)" != "$deps_hash" ]]; then
    step "installing pinned dependencies (first run takes a few minutes)"
    "$venv/bin/python" -m pip install --quiet --upgrade pip==25.3
    "$venv/bin/python" -m pip install --quiet -r requirements.txt -c constraints.txt
    "$venv/bin/python" -m pip install --quiet --no-deps -e .
    step "rewriting the ROS wheels' CMake exports to this interpreter"
    "$venv/bin/python" scripts/fix_wheel_cmake.py "$venv"
    echo "$deps_hash" > "$venv/.deps-stamp"
    rm -f "$repo/ros_ws/.build-stamp"
fi

# 2. colcon build of ros_ws (only when its sources changed)
# config/ too: the ament package installs its data files (parameter files, stack description, sequences, ...) into
# share/.
ws_hash="$({ find ros_ws/src config -type f -not -name '*.pyc' -print0; } \
    | sort -z | xargs -0 sha256sum | sha256sum | cut -c1-16)"
if [[ "$(cat ros_ws/.build-stamp 2>/dev/null)" != "$ws_hash" || ! -f ros_ws/install/setup.bash ]]; then
    # colcon names each package as it starts and ends, and on a terminal (only there: in a log its updates would
    # be noise) its status line counts the time meanwhile; the message package takes minutes the first time.
    step "building ros_ws with colcon"
    (
        source "$venv/bin/activate"
        export CMAKE_PREFIX_PATH="$venv" AMENT_PREFIX_PATH="$venv"
        cd ros_ws
        colcon --log-base log build --symlink-install \
            --event-handlers console_direct- console_cohesion- summary+ \
            --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$venv/bin/python" >&2
    )
    echo "$ws_hash" > ros_ws/.build-stamp
fi
# 3. compiled finger search and its lookahead fields (kept on disk; a few minutes once, then a moment), step by step
"$venv/bin/python" -m planner prepare-design
step "ready"

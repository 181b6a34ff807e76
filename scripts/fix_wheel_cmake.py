"""Point the ROS wheels' exported CMake targets at this interpreter's include dirs.

The wheels were built under /opt/python/cp311-cp311 and their *Export*.cmake files keep those
paths; CMake refuses imported targets whose include directories do not exist.
"""
import pathlib
import sys
import sysconfig

import numpy

BUILD_MACHINE_PYTHON_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
BUILD_MACHINE_NUMPY_INCLUDE = (
    "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"
)


def main(venv: str) -> None:
    replacements = {
        BUILD_MACHINE_NUMPY_INCLUDE: numpy.get_include(),
        BUILD_MACHINE_PYTHON_INCLUDE: sysconfig.get_paths()["include"],
    }
    changed = 0
    for cmake_file in pathlib.Path(venv, "share").rglob("*.cmake"):
        text = cmake_file.read_text()
        fixed = text
        for old, new in replacements.items():
            fixed = fixed.replace(old, new)
        if fixed != text:
            cmake_file.write_text(fixed)
            changed += 1
    print(f"[setup] fixed {changed} CMake export files", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv[1])

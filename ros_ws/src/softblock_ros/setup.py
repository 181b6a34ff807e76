import os
from pathlib import Path

from setuptools import find_packages, setup

package_name = "softblock_ros"
# The repository's config/ (the core's package data, softblock_config) is installed into share/ too, every data
# file of it (parameter files, the stack description, sequences, assemblies, objects, the Foxglove layout): the
# launch file finds them there through the ament index.
CONFIG = Path("../../../config")


def config_data_files() -> list[tuple[str, list[str]]]:
    folders: dict[str, list[str]] = {}
    for path in sorted(CONFIG.rglob("*")):
        if path.is_file() and path.suffix not in (".py", ".pyc") and "__pycache__" not in path.parts:
            folder = Path("share", package_name, "config", path.parent.relative_to(CONFIG))
            folders.setdefault(os.path.normpath(folder), []).append(str(path))
    return sorted(folders.items())


setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", ["launch/softblock.launch.py"]),
        *config_data_files(),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="softblock maintainers",
    maintainer_email="maintainers@softblock.dev",
    description="ROS 2 nodes of the soft building-block robot stack.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "assembly_state = softblock_ros.assembly_state_node:main",
            "estimator = softblock_ros.estimator_node:main",
            "foxglove_bridge = softblock_ros.foxglove_bridge_node:main",
            "hv_driver = softblock_ros.hv_driver_node:main",
            "planner = softblock_ros.planner_node:main",
            "launcher = softblock_ros.launcher:main",
            "recorder = softblock_ros.recording.cli:record_main",
            "player = softblock_ros.recording.cli:play_main",
            "analyze_recording = recording.cli:analyze_main",
            "sequencer = softblock_ros.sequencer_node:main",
            "sim_arm = softblock_ros.sim_arm_node:main",
            "sim_camera = softblock_ros.sim_camera_node:main",
            "hv_console = softblock_ros.hv_console:main",
            "run_sequence = softblock_ros.run_sequence:main",
            "demo = softblock_ros.demo:main",
            "demo_reconfigure = softblock_ros.demo_reconfigure:main",
        ],
    },
)

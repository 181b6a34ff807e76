from glob import glob

from setuptools import find_packages, setup

package_name = "softblock_ros"
# The stack's parameter files and description live in the repository's config/ (also the core's package data);
# installed into share/ too, where the launch file finds them through the ament index.
CONFIG_FILES = sorted(glob("../../../config/*.yaml"))

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", ["launch/softblock.launch.py"]),
        ("share/" + package_name + "/config", CONFIG_FILES),
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

"""The whole stack for a ROS 2 apt install, from the same stack description as the launcher (config/stack.yaml).

    ros2 launch softblock_ros softblock.launch.py [namespace:=/robot1]

Each node of the description (but the optional ones, e.g. the live view) runs as ``ros2 run softblock_ros <executable>`` with its parameter files from
this package's share/softblock_ros/config and its niceness as a ``nice`` prefix, in the DDS network of the
description's `network` section (over the environment's; LOCALHOST when neither chooses a range).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from softblock_ros.stack import load_stack


def generate_launch_description() -> LaunchDescription:
    stack = load_stack(os.path.join(get_package_share_directory("softblock_ros"), "config", "stack.yaml"))
    namespace = LaunchConfiguration("namespace")
    nodes = [Node(package="softblock_ros", executable=spec.executable, name=spec.name, namespace=namespace,
                  parameters=[str(path) for path in spec.parameters], output="screen",
                  prefix=f"nice -n {spec.niceness}" if spec.niceness else None)
             for spec in stack.nodes if not spec.optional]
    network = [SetEnvironmentVariable(name, value) for name, value in stack.network.variables(os.environ).items()]
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value=stack.namespace, description="namespace of every node"),
        *network, *nodes])

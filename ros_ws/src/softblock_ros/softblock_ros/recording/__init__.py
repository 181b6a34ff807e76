"""The recorder and player nodes and the `python -m softblock_ros.recording` command line.

The files, replay timing and analysis they use are the ROS-free core package `recording`.
"""

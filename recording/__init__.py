"""Recordings without ROS: MCAP files with the ROS 2 profile (write, describe, recover), replay timing, analysis.

The recorder and player nodes that feed and read these files live in softblock_ros.recording.
"""

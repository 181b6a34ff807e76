"""Recording to MCAP (ROS 2 profile), replay, recovery and grasp analysis.

The analysis, file and definition modules never import rclpy; the recorder and player nodes do.
"""

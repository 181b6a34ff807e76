"""ROS 2 nodes: thin wrappers over the planner, hv_driver and sim_fallback core packages."""

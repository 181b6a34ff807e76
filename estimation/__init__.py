"""Block angles and assembly mistakes estimated from a side-view silhouette of a chain (no ROS)."""

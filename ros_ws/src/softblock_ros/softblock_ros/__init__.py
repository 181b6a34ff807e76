"""ROS 2 nodes: thin wrappers over the planner, hv_driver and sim_fallback core packages."""
import os

# Message setters check field types only when this is "1" (read when a message module is imported). Without
# it a wrong type (a numpy bool in a bool field) passes the setter and the C conversion asserts, which aborts
# the whole node; with it, the setter raises and the node's callback wrapper answers with the error.
os.environ.setdefault("ROS_PYTHON_CHECK_FIELDS", "1")

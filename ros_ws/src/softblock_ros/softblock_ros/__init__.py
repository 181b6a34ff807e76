"""ROS 2 nodes: thin wrappers over the planner, hv_driver and sim_fallback core packages."""
import os

# Message setters check field types only when this is "1" (read when a message module is imported). Without
# it a wrong type (a numpy bool in a bool field) passes the setter and the C conversion asserts, which aborts
# the whole node; with it, the setter raises and the node's callback wrapper answers with the error.
os.environ.setdefault("ROS_PYTHON_CHECK_FIELDS", "1")

# Fast DDS sends a published sample from a thread of its own in this mode; in its default (SYNCHRONOUS) it sends in
# the caller's thread, and rclpy holds the interpreter lock through publish(). A reader that stopped answering (its
# process stopped or starved) then blocked publish() for up to 1 s, and with it every thread of the process: the HV
# driver's control loop and its simulated supply's link went silent, and clients counted the driver as lost.
# Read by rmw_fastrtps when a context is initialised; the HV driver warns when another mode was chosen.
PUBLICATION_MODE_VARIABLE, PUBLICATION_MODE = "RMW_FASTRTPS_PUBLICATION_MODE", "ASYNCHRONOUS"
os.environ.setdefault(PUBLICATION_MODE_VARIABLE, PUBLICATION_MODE)

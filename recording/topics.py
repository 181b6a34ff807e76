"""Which topics are what, for recording and replay: hidden, command and state topics. No rclpy import."""
import re

# Topics the stack obeys rather than reports on, as the HV driver subscribes to them:
#   hv/heartbeat           softblock_interfaces/msg/HvHeartbeat  the controlling client's sign of life (the
#                          watchdog); signed, each counter counting once, so a replayed one is refused
#   assembly/safe_voltage  std_msgs/msg/Float64 (latched)       the voltage ceiling
# Replayed into a live stack they would feed the watchdog or move the ceiling, so the player leaves them out
# unless asked. The driver's other inputs are services and an action (hv/claim_control, hv/release_control,
# hv/estop, hv/reset_faults, hv/inject_fault, hv/ramp), which a player cannot call; what they leave in a
# recording (service events, action feedback and status) is hidden and left out too.
COMMAND_TOPICS = ("hv/heartbeat", "assembly/safe_voltage")
_COMMAND = re.compile(r"(^|/)(" + "|".join(map(re.escape, COMMAND_TOPICS)) + r")$")


def is_hidden(topic: str) -> bool:
    """Hidden topics (a name part starting with '_': action and service internals), as ros2 bag."""
    return any(part.startswith("_") for part in topic.split("/"))


def is_command_topic(topic: str) -> bool:
    """A topic that commands or limits a node (in any namespace); action goals, feedback and status
    and service events (hidden topics) count as commands too."""
    return bool(_COMMAND.search(topic)) or is_hidden(topic)


# Topics live clients watch to know the state of the stack: the sequencer and the estimator take hv/state
# (a stale one is how a dead driver is noticed), the camera and the estimator the assembly and the image, the
# simulated camera also what the simulated world has built (sim/assembly_built, latched), TF viewers /tf and
# /tf_static, the console /diagnostics, log viewers /rosout. Replayed under their own names into a live domain, a
# recorded hv/state hid a dead driver for 28 s; the player moves them to a namespace unless asked.
STATE_TOPICS = ("hv/state", "assembly/current", "camera/silhouette", "sim/assembly_built", "tf", "tf_static",
                "diagnostics", "rosout")
_STATE = re.compile(r"(^|/)(" + "|".join(map(re.escape, STATE_TOPICS)) + r")$")


def is_state_topic(topic: str) -> bool:
    """A topic live clients watch for the stack's state (in any namespace)."""
    return bool(_STATE.search(topic))


# A namespace as rcl takes it (``-r __ns:=/robot1``): absolute, each part letters, digits and '_' from a letter on,
# without '__' (rcl's mark of its own names); "a b", "robot1" and "/a//b" end a node's start in rcl.
_NAMESPACE = re.compile(r"(/[A-Za-z][A-Za-z0-9_]*)+")


def is_namespace(text: str) -> bool:
    """Whether ``text`` is a namespace every ROS node takes, e.g. /robot1 or /lab/robot1."""
    return bool(_NAMESPACE.fullmatch(text)) and "__" not in text

"""Which topics are what, for recording and replay: hidden and command topics. No rclpy import."""
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

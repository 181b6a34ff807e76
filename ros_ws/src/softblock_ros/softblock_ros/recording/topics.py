"""Which topics are what, for recording and replay: hidden and command topics. No rclpy import."""
import re

# Topics the stack obeys rather than reports on: the HV driver takes the controlling client's
# heartbeat (its watchdog) and the assembly's safe voltage (its ceiling) from them. Replayed into a
# live stack they would feed the watchdog or move the ceiling, so the player leaves them out unless
# asked.
COMMAND_TOPICS = re.compile(r"(^|/)(hv/heartbeat|assembly/safe_voltage)$")


def is_hidden(topic: str) -> bool:
    """Hidden topics (a name part starting with '_': action and service internals), as ros2 bag."""
    return any(part.startswith("_") for part in topic.split("/"))


def is_command_topic(topic: str) -> bool:
    """A topic that commands or limits a node (in any namespace); action goals, feedback and status
    and service events (hidden topics) count as commands too."""
    return bool(COMMAND_TOPICS.search(topic)) or is_hidden(topic)

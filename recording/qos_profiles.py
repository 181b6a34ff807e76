"""The `offered_qos_profiles` channel metadata of a recording, parsed bounded (planner.bounded_yaml). No rclpy.

rosbag2 (Jazzy) writes it as a YAML list of maps, one per publisher; a file from elsewhere may hold anything.
"""
from planner.bounded_yaml import parse_yaml

MAX_QOS_TEXT = 64 * 1024  # [characters] a profile is about 400; a topic has a few publishers


def parse_offered_qos(text: str, topic: str = "") -> list[dict]:
    """The recorded profiles as maps; an empty string (no QoS recorded) gives []. ValueError (one line, naming
    the topic) for anything but a bounded YAML list of maps."""
    where = f"offered_qos_profiles of {topic or 'a channel'}"
    profiles = parse_yaml(text, where, MAX_QOS_TEXT) if text.strip() else []
    if not isinstance(profiles, list) or not all(isinstance(p, dict) for p in profiles):
        raise ValueError(f"{where}: not a YAML list of QoS maps")
    return profiles

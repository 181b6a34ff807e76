"""QoS <-> MCAP channel metadata, in the `offered_qos_profiles` YAML that rosbag2 (Jazzy) writes.

Recording asks for what every publisher offers (reliable / transient_local only when all of
them offer it, as rosbag2 does), so latched topics are captured; playback offers what was
recorded, so latched topics stay latched.
"""
import yaml
from rclpy.duration import Duration
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile,
                       ReliabilityPolicy)

# Depth of recorder subscriptions: room for bursts at the stack's rates while the writer compresses.
RECORD_DEPTH = 1000
# Depth of player publishers when the recording holds none (DDS discovery reports depth 0);
# rosbag2's player uses the same default.
PLAYBACK_DEPTH = 10
_NANOSECONDS = 1_000_000_000


def _duration_map(duration: Duration) -> dict:
    seconds, nanoseconds = divmod(duration.nanoseconds, _NANOSECONDS)
    return {"sec": seconds, "nsec": nanoseconds}


def profile_to_map(profile: QoSProfile) -> dict:
    """One QoS profile as rosbag2 Jazzy serialises it (string enums, keys in its order)."""
    return {
        "history": profile.history.short_key,
        "depth": profile.depth,
        "reliability": profile.reliability.short_key,
        "durability": profile.durability.short_key,
        "deadline": _duration_map(profile.deadline),
        "lifespan": _duration_map(profile.lifespan),
        "liveliness": profile.liveliness.short_key,
        "liveliness_lease_duration": _duration_map(profile.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": profile.avoid_ros_namespace_conventions,
    }


def offered_qos_yaml(profiles: list[QoSProfile]) -> str:
    """The `offered_qos_profiles` channel metadata value for the publishers of a topic."""
    return yaml.safe_dump([profile_to_map(p) for p in profiles], sort_keys=False,
                          default_flow_style=False)


def _all_offer(profiles: list[dict], key: str, value: str) -> bool:
    return bool(profiles) and all(profile.get(key) == value for profile in profiles)


def recording_qos(offered: list[QoSProfile]) -> QoSProfile:
    """Subscription QoS that matches every publisher of a topic and keeps latched samples."""
    offers = [profile_to_map(profile) for profile in offered]
    reliable = _all_offer(offers, "reliability", "reliable")
    latched = _all_offer(offers, "durability", "transient_local")
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=RECORD_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def playback_qos(recorded: list[dict]) -> QoSProfile:
    """Publisher QoS that offers what the recorded publishers offered. A volatile topic's publisher keeps every
    sample until it is sent: the stack publishes asynchronously (see softblock_ros), and a burst of a replay
    outran the sending thread, whose history then dropped samples never sent (a replayed recording came back
    short). A latched topic keeps its recorded depth, which is what a late joiner gets; the player lets no write
    push a sample its subscribers have not acknowledged out of that depth (PlayerNode._wait_for_room)."""
    reliable = not recorded or _all_offer(recorded, "reliability", "reliable")
    latched = _all_offer(recorded, "durability", "transient_local")
    depth = max([int(p.get("depth") or 0) for p in recorded] + [PLAYBACK_DEPTH])
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST if latched else HistoryPolicy.KEEP_ALL, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        liveliness=LivelinessPolicy.AUTOMATIC)

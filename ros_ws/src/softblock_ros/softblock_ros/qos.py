"""QoS profiles the stack's nodes share: latched state, and streams a reliable reader can repair."""
import math

from rclpy.qos import DurabilityPolicy, QoSProfile

# The newest value, kept for readers that join later (rosbag2 and RViz call this "latched").
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Fast DDS repairs a sample a reliable reader missed (dropped by a full socket or shared-memory port while the
# reader's process was starved, or by a lossy link) at the writer's next periodic heartbeat, every 3 s by default;
# only a sample still in the writer's history can be sent again. 8 s of history let a reader such as the recorder
# repair a loss and a lost repair; a depth of 10 at 50 Hz (0.2 s) let a loaded host's recording lose samples.
REPAIR_HISTORY_S = 8.0  # [s]


def stream_qos(rate_hz: float) -> QoSProfile:
    """Reliable, volatile: a stream published at ``rate_hz`` [Hz] that keeps REPAIR_HISTORY_S of samples."""
    return QoSProfile(depth=max(1, math.ceil(REPAIR_HISTORY_S * rate_hz)))

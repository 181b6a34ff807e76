"""Test-wide settings: DDS stays on loopback and every test process gets its own ROS domain."""
import os

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# One domain per test process (xdist workers included) so parallel runs never cross-talk.
os.environ["ROS_DOMAIN_ID"] = str(10 + os.getpid() % 90)
os.environ.setdefault("MPLBACKEND", "Agg")

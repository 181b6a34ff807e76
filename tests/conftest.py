"""Test-wide settings: DDS stays on loopback and every test process gets its own ROS domain."""
import hashlib
import os

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# One domain per test process so parallel runs never cross-talk: the workers of one pytest-xdist run
# take consecutive domains from a slot derived from the run's id (a plain run: from its pid).
_run = os.environ.get("PYTEST_XDIST_TESTRUNUID", str(os.getpid()))
_worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
os.environ["ROS_DOMAIN_ID"] = str(10 + (int(hashlib.sha256(_run.encode()).hexdigest(), 16) + _worker) % 90)
os.environ.setdefault("MPLBACKEND", "Agg")

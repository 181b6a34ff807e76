"""Test-wide settings: DDS stays on loopback and every test module gets its own ROS domain."""
import hashlib
import itertools
import os

import pytest

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("MPLBACKEND", "Agg")

# Parallel runs never cross-talk: worker w of an n-worker pytest-xdist run gives its m-th module the
# domain slot w + n*m, counted from an offset derived from the run's id (a plain run: from its pid).
# 90 slots: distinct while no worker runs more than 90/n modules.
_RUN = os.environ.get("PYTEST_XDIST_TESTRUNUID", str(os.getpid()))
_OFFSET = int(hashlib.sha256(_RUN.encode()).hexdigest(), 16)
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
_MODULES = itertools.count()


def _domain(module_index: int) -> str:
    return str(10 + (_OFFSET + _WORKER + _WORKERS * module_index) % 90)


os.environ["ROS_DOMAIN_ID"] = _domain(next(_MODULES))


@pytest.fixture(scope="module", autouse=True)
def ros_domain_per_module():
    """A fresh domain for each module: nodes an earlier module left in the DDS graph (a killed process
    stays listed until its lease runs out) never show up in this one's topic lists."""
    os.environ["ROS_DOMAIN_ID"] = _domain(next(_MODULES))

"""Test-wide settings: DDS stays on loopback and every test module gets its own ROS domain."""
import hashlib
import itertools
import os

import pytest

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("MPLBACKEND", "Agg")

# Parallel runs never cross-talk: worker w of an n-worker pytest-xdist run gives its m-th module the
# domain slot w + n*m, counted from an offset derived from the run's id (a plain run: from its pid).
# Slots: domains 10-99 by default, distinct while no worker runs more than 90/n modules. Suites that
# run at the same time on one machine (two checkouts) each take their own range:
# SOFTBLOCK_TEST_DOMAINS=100-160.
_FIRST, _LAST = (int(bound) for bound in os.environ.get("SOFTBLOCK_TEST_DOMAINS", "10-99").split("-"))
if not 0 <= _FIRST <= _LAST <= 232:
    raise ValueError(f"SOFTBLOCK_TEST_DOMAINS={_FIRST}-{_LAST}: a range within 0-232 (Fast DDS's port limit)")
_RUN = os.environ.get("PYTEST_XDIST_TESTRUNUID", str(os.getpid()))
_OFFSET = int(hashlib.sha256(_RUN.encode()).hexdigest(), 16)
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
_MODULES = itertools.count()


def _domain(module_index: int) -> str:
    return str(_FIRST + (_OFFSET + _WORKER + _WORKERS * module_index) % (_LAST - _FIRST + 1))


os.environ["ROS_DOMAIN_ID"] = _domain(next(_MODULES))


@pytest.fixture(scope="module", autouse=True)
def ros_domain_per_module():
    """A fresh domain for each module: nodes an earlier module left in the DDS graph (a killed process
    stays listed until its lease runs out) never show up in this one's topic lists."""
    os.environ["ROS_DOMAIN_ID"] = _domain(next(_MODULES))

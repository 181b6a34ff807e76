"""Test-wide settings: DDS stays on loopback, every test module gets its own ROS domain, and every process a
test starts ends with it."""
import faulthandler
import hashlib
import itertools
import os
import sys
import threading

import pytest
from hypothesis import settings
from processes import adopt_orphans, descendants, kill_tree, reap
from ros_domains import DEFAULT_TEST_DOMAINS, domain_for
from xdist.scheduler import LoadScopeScheduling

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("MPLBACKEND", "Agg")
# Message setters check field types (as the nodes do, see softblock_ros/__init__.py); read at message import.
os.environ.setdefault("ROS_PYTHON_CHECK_FIELDS", "1")

# Hypothesis' deadline per example (200 ms by default) is a wall-clock assertion: on a loaded host it fails
# correct code (seen: 260 ms for a pure geometry example at a load average of 20). Examples are bounded by
# pytest-timeout instead, as every test is. The suite draws the same examples on every run, so that a run's outcome
# never depends on its luck; HYPOTHESIS_PROFILE=explore draws new ones on every run (1000 where a test sets no count)
# to hunt for counterexamples: keep each one found as an @example.
settings.register_profile("suite", deadline=None, derandomize=True)
settings.register_profile("explore", deadline=None, max_examples=1000)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "suite"))

# Parallel runs never cross-talk: each pytest-xdist worker owns a block of the domains (10-99 by default)
# and gives each of its modules the next one, counted from an offset derived from the run's id (a plain
# run: from its pid); see ros_domains.domain_for. Suites that run at the same time on one machine (two
# checkouts) each take their own range: SOFTBLOCK_TEST_DOMAINS=100-160.
_FIRST, _LAST = (int(bound) for bound in os.environ.get("SOFTBLOCK_TEST_DOMAINS", DEFAULT_TEST_DOMAINS).split("-"))
if not 0 <= _FIRST <= _LAST <= 232:
    raise ValueError(f"SOFTBLOCK_TEST_DOMAINS={_FIRST}-{_LAST}: a range within 0-232 (Fast DDS's port limit)")
_RUN = os.environ.get("PYTEST_XDIST_TESTRUNUID", str(os.getpid()))
_OFFSET = int(hashlib.sha256(_RUN.encode()).hexdigest(), 16)
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
_MODULES = itertools.count()


def _domain(module_index: int) -> str:
    return str(domain_for(_FIRST, _LAST, _OFFSET, _WORKER, _WORKERS, module_index))


os.environ["ROS_DOMAIN_ID"] = _domain(next(_MODULES))


@pytest.fixture(scope="module", autouse=True)
def ros_domain_per_module():
    """A fresh domain for each module: nodes an earlier module left in the DDS graph (a killed process
    stays listed until its lease runs out) never show up in this one's topic lists."""
    os.environ["ROS_DOMAIN_ID"] = _domain(next(_MODULES))


# The stack tier's modules in the order its schedule hands them out (pytest_collection_modifyitems sorts them so;
# any other module follows). The two longest (two-host ~110 s, demo ~85 s) start, one on each worker. xdist gives
# the next module to the first worker left with two tests to run: the two-host one, whose last test then still
# has ~40 s to go, so that one gets the short launch smoke tests and the demo's worker the reconfiguration demo
# (~30 s). In the other order the two-host worker took the 30 s demo as well: 145 s instead of ~120 s.
STACK_ORDER = ("tests/twohosts/", "tests/e2e/test_demo.py", "tests/e2e/test_launch_smoke.py")


def _stack_rank(nodeid: str) -> int:
    return next((rank for rank, prefix in enumerate(STACK_ORDER) if nodeid.startswith(prefix)), len(STACK_ORDER))


class StackScheduling(LoadScopeScheduling):
    """pytest-xdist's schedule of the stack tier (``--dist-stack``): each module on one worker (its tests
    share a module-wide stack), in collection order, which STACK_ORDER sets. (xdist's ``--dist loadgroup`` does
    not group under pytest 9: its nodeid suffix no longer takes.)"""

    def __init__(self, config, log=None):
        config.option.loadscopereorder = False  # keep the collection order
        super().__init__(config, log)

    def _split_scope(self, nodeid: str) -> str:
        return nodeid.split("::", 1)[0]


def pytest_addoption(parser):
    parser.addoption("--dist-stack", action="store_true",
                     help="with -n: the stack tier's schedule (tests/conftest.py StackScheduling)")


def pytest_xdist_make_scheduler(config, log):
    return StackScheduling(config, log) if config.getoption("dist_stack") else None


# The tiers are the markers pyproject.toml registers; tests/test_tiers.py checks that every test has one.
_TIERS_OF = pytest.StashKey[dict]()


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Before `-m` deselects any: the tier markers of every collected test (`make test` and `make test-fast`
    collect the whole suite, whichever tier they run)."""
    tiers = {line.split(":")[0] for line in config.getini("markers")}
    config.stash[_TIERS_OF] = {item.nodeid: [mark.name for mark in item.iter_markers() if mark.name in tiers]
                               for item in items}
    items.sort(key=lambda item: _stack_rank(item.nodeid))  # stable: within a rank, the collection order


@pytest.fixture(scope="session")
def collected_tiers(request) -> dict[str, list[str]]:
    """node id -> its tier markers, of every test this run collected."""
    return request.config.stash[_TIERS_OF]


adopt_orphans()  # a test process killed with its children alive leaves them in this tree, not to init
_TIMED_OUT = pytest.StashKey[bool]()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    if report.failed and "from pytest-timeout" in report.longreprtext:
        item.stash[_TIMED_OUT] = True
    return report


def _kill_new_processes(before: set[int]) -> None:
    leftover = descendants(os.getpid()) - before
    if leftover:
        kill_tree(leftover)
        reap(leftover)


@pytest.fixture(autouse=True)
def kill_processes_of_a_timed_out_test(request):
    """What a test started is killed as soon as pytest-timeout fails it (timeout_method = signal raises in
    the test, so this teardown runs). Processes of passing tests may outlive them: module fixtures start
    some (the HV driver's simulated supply) in the tests."""
    before = descendants(os.getpid())
    yield
    if request.node.stash.get(_TIMED_OUT, False):
        _kill_new_processes(before)


@pytest.fixture(scope="module", autouse=True)
def kill_processes_left_by_a_module():
    """Whatever a test module's tests and fixtures started and left running is killed when it ends."""
    before = descendants(os.getpid())
    yield
    _kill_new_processes(before)


# A test stuck in C code (e.g. a wait inside rclpy) never sees pytest-timeout's signal. Then, this much
# later, the last resort kills every process below this one and ends the worker, as pytest-timeout's
# thread method does, so nothing outlives the run.
LAST_RESORT_GRACE = 60.0  # [s] after the test's timeout
_LAST_RESORT = pytest.StashKey[threading.Timer]()


def _last_resort(item) -> None:
    capture = item.config.pluginmanager.getplugin("capturemanager")
    if capture is not None:
        capture.suspend_global_capture(in_=True)  # so the message and the stacks reach the terminal
    sys.stderr.write(f"\n{item.nodeid} did not end {LAST_RESORT_GRACE:.0f} s after its timeout; "
                     "killing its processes and this worker\n")
    faulthandler.dump_traceback(all_threads=True)
    kill_tree(descendants(os.getpid()))
    os._exit(1)


def pytest_timeout_set_timer(item, settings):
    if settings.timeout > 0:
        timer = threading.Timer(settings.timeout + LAST_RESORT_GRACE, _last_resort, args=(item,))
        timer.daemon = True
        timer.start()
        item.stash[_LAST_RESORT] = timer
    # returning None lets pytest-timeout set its own (signal) timer as well


def pytest_timeout_cancel_timer(item):
    timer = item.stash.get(_LAST_RESORT, None)
    if timer is not None:
        timer.cancel()

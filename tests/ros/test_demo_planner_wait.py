"""The demo waits for the planner by its word, not by the clock: its first request goes out once the planner
says it is ready, however long a busy machine keeps the niced planner from starting, and a planner that exits
first ends the wait at once, naming its exit code."""
import io
import signal
import sys

import pytest
from ros_testing import wait_for

from softblock_ros import demo
from softblock_ros.client import ClientError
from softblock_ros.launcher import Stack

pytestmark = pytest.mark.integration


class StandInPlanner(Stack):
    """Runs ``code`` in place of the planner node."""

    def __init__(self, code: str, **kwargs):
        super().__init__(nodes=[demo.PLANNER], **kwargs)
        self.code = code

    def command(self, name):
        return [sys.executable, "-c", self.code]


def test_the_wait_lasts_while_the_planner_is_held_back_and_ends_with_its_ready_line(tmp_path):
    go = tmp_path / "go"
    code = (f"import pathlib, time\nprint('preparing', flush=True)\n"
            f"while not pathlib.Path({str(go)!r}).exists(): time.sleep(0.01)\n"
            f"print('[INFO] [planner]: {demo.PLANNER_READY}, table of 84 designs', flush=True)\n"
            "time.sleep(60)")
    output = io.StringIO()
    stack = StandInPlanner(code, output=output)
    ready = stack.watch(demo.PLANNER, demo.PLANNER_READY)
    with stack:
        wait_for(lambda: "[planner] preparing" in output.getvalue(), what="the stand-in planner to start")
        planner = stack.processes[demo.PLANNER]
        planner.send_signal(signal.SIGSTOP)  # a host that gives the niced planner no CPU
        go.touch()
        assert ready.line is None
        planner.send_signal(signal.SIGCONT)
        demo.wait_for_planner(stack, ready)
        assert ready.line.endswith(f"{demo.PLANNER_READY}, table of 84 designs")


def test_a_planner_that_exits_before_it_is_ready_ends_the_wait_at_once(monkeypatch):
    monkeypatch.setattr(demo, "PLANNER_START_TIMEOUT", 3600.0)  # only the exit can end this wait in time
    stack = StandInPlanner("import sys; print('no table', flush=True); sys.exit(3)", output=io.StringIO())
    ready = stack.watch(demo.PLANNER, demo.PLANNER_READY)
    with stack, pytest.raises(ClientError, match="the planner ended with code 3 before it was ready"):
        demo.wait_for_planner(stack, ready)


def test_a_planner_that_says_nothing_within_the_bound_is_named(monkeypatch):
    monkeypatch.setattr(demo, "PLANNER_START_TIMEOUT", 0.2)
    stack = StandInPlanner("import time; time.sleep(60)", output=io.StringIO(), stop_timeout=5.0)
    ready = stack.watch(demo.PLANNER, demo.PLANNER_READY)
    with stack, pytest.raises(ClientError, match="the planner was not ready within 0.2 s"):
        demo.wait_for_planner(stack, ready)


def test_the_planner_node_says_the_line_the_demo_waits_for(tmp_path):
    params = tmp_path / "params.yaml"
    params.write_text("planner:\n  ros__parameters:\n    prepare_finger_search: false\n")
    stack = Stack(nodes=[demo.PLANNER], params=params, output=io.StringIO())
    ready = stack.watch(demo.PLANNER, demo.PLANNER_READY)
    with stack:
        demo.wait_for_planner(stack, ready)
    assert ready.line is not None and "table of 84 designs" in ready.line

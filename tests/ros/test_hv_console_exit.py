"""`hv_console` as a user runs it ends cleanly: `quit` (or the end of input) and Ctrl-C exit 0, without the
abort ("terminate called without an active exception") that a spinner thread still inside rclpy at exit caused."""
import signal
import subprocess
import sys

import pytest
from processes import run, start, stop

pytestmark = pytest.mark.integration

TIMEOUT = 120.0  # [s] liveness bound only: a loaded host imports rclpy slowly
CONSOLE = [sys.executable, "-m", "softblock_ros.hv_console"]


@pytest.mark.parametrize("typed", ["quit\n", ""], ids=["quit", "end of input"])
def test_the_console_ends_with_its_input_and_exits_zero(typed, tmp_path):
    (tmp_path / "typed").write_text(typed)
    with open(tmp_path / "typed") as keyboard:
        ended = run([*CONSOLE, "--commands"], TIMEOUT, stdin=keyboard)
    assert ended.returncode == 0, ended.stderr[-2000:]
    assert "terminate called" not in ended.stderr


def test_ctrl_c_ends_the_status_lines_with_exit_zero():
    console = start([*CONSOLE, "--period", "0.1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert console.stdout.readline().startswith("hv/state")  # it runs: the first status line
    assert stop(console, TIMEOUT, signal.SIGINT) == 0, console.stderr.read()[-2000:]

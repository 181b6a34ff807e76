"""Stack launcher: nodes as processes reachable over ROS, prefixed output, clean stop on SIGTERM and SIGHUP
(wherever the signal lands), nodes that end with a killed launcher, non-zero exit when a node dies, SIGKILL for
a node that ignores SIGINT. What it and the nodes refuse to start with: test_launcher_inputs.py."""
import io
import os
import signal
import subprocess
import sys
import textwrap

import pytest
import rclpy
from processes import _parents, reap
from ros_testing import Inbox, wait_for
from softblock_interfaces.msg import Assembly

from softblock_ros.launcher import NodeDied, Stack, main
from softblock_ros.qos import LATCHED

pytestmark = pytest.mark.integration


@pytest.fixture
def params(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text("assembly_state:\n  ros__parameters:\n    frame_id: launcher_test_frame\n")
    return path


def test_stack_runs_nodes_with_the_params_file_and_stops_them_cleanly(ros_context, spin, params):
    output = io.StringIO()
    with Stack(nodes=["assembly_state"], params=params, output=output) as stack:
        client = rclpy.create_node("launcher_test_client", context=ros_context)
        inbox = Inbox(client, Assembly, "assembly/current", LATCHED)
        spin(client)
        assert inbox.wait().header.frame_id == "launcher_test_frame"
        # The node publishes its latched assembly before it logs its start: a stop in between is a clean stop
        # without the line.
        wait_for(lambda: "publishing at" in output.getvalue(), what="the node's start-up line")
        assert stack.dead() == {}
    assert stack.stop() == {"assembly_state": 0}, output.getvalue()[-3000:]
    lines = output.getvalue().splitlines()
    # The launcher's own lines (first: where DDS traffic goes, loopback unless chosen) and the node's, prefixed.
    assert lines[0].startswith("[launcher] network: DDS discovery LOCALHOST, static peers none, domain ")
    assert all(line.startswith("[assembly_state] ") for line in lines[1:])
    assert any("publishing at" in line for line in lines)


def test_namespace_moves_the_nodes_relative_names(ros_context, spin, tmp_path):
    params = tmp_path / "params.yaml"  # a /**/ key matches the node in any namespace
    params.write_text("/**/assembly_state:\n  ros__parameters:\n    frame_id: namespaced_frame\n")
    client = rclpy.create_node("launcher_namespace_client", context=ros_context)
    inbox = Inbox(client, Assembly, "/robot7/assembly/current", LATCHED)
    spin(client)
    with Stack(nodes=["assembly_state"], params=params, namespace="/robot7", output=io.StringIO()):
        assert inbox.wait().header.frame_id == "namespaced_frame"


def test_a_node_that_dies_ends_the_wait(params):
    with Stack(nodes=["assembly_state"], params=params, output=io.StringIO()) as stack:
        stack.processes["assembly_state"].kill()
        with pytest.raises(NodeDied, match="node assembly_state exited with code -9"):
            stack.wait()


class SigintIgnoringStack(Stack):
    """Runs a stand-in process that ignores SIGINT instead of the node."""

    def command(self, name):
        code = "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print('up', flush=True); time.sleep(60)"
        return [sys.executable, "-c", code]


def test_a_node_that_ignores_sigint_is_killed_after_the_timeout():
    output = io.StringIO()
    with SigintIgnoringStack(nodes=["planner"], output=output, stop_timeout=0.5) as stack:
        wait_for(lambda: "[planner] up" in output.getvalue(), what="the stand-in process to start")
    assert stack.processes["planner"].returncode == -signal.SIGKILL
    assert "[launcher] planner: did not stop within 0.5 s, killing it" in output.getvalue()


def launch(*args):
    return subprocess.Popen([sys.executable, "-m", "softblock_ros.launcher", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def test_cli_forwards_sigterm_and_exits_zero(params):
    launcher = launch("--nodes", "assembly_state", "--params", str(params))
    for line in launcher.stdout:  # until the node is up
        if line.startswith("[assembly_state]") and "publishing at" in line:
            break
    launcher.send_signal(signal.SIGTERM)
    rest = launcher.stdout.read()
    assert launcher.wait() == 0
    assert "launcher: stopped (assembly_state=0)" in rest


def test_cli_exits_non_zero_when_a_node_fails(tmp_path):
    params = tmp_path / "bad.yaml"
    params.write_text("assembly_state:\n  ros__parameters:\n    assembly_file: /nonexistent/assembly.yaml\n")
    launcher = launch("--nodes", "assembly_state", "--params", str(params))
    output, _ = launcher.communicate()
    assert launcher.returncode == 1
    assert "cannot read assembly file /nonexistent/assembly.yaml" in output
    assert "launcher: node assembly_state exited with code 1" in output


def test_cli_refuses_unknown_nodes(capsys):
    assert main(["--nodes", "assembly_state,teleporter"]) == 2
    assert "unknown nodes ['teleporter']" in capsys.readouterr().err


def test_the_planner_runs_at_lower_priority_than_the_hv_driver(params):
    import os

    with Stack(nodes=["assembly_state", "planner"], params=params, output=io.StringIO()) as stack:
        niceness = {name: os.getpriority(os.PRIO_PROCESS, p.pid) for name, p in stack.processes.items()}
    base = os.getpriority(os.PRIO_PROCESS, 0)
    assert niceness == {"assembly_state": base, "planner": min(base + 10, 19)}


SIGNAL_AT_EVERY_LINE = textwrap.dedent("""
    import os, signal, sys
    from softblock_ros import launcher

    class TracedStack(launcher.Stack):
        # No nodes; SIGTERM is sent at the target-th line the interpreter runs inside wait(), including
        # the lines of whatever wait() calls (threading's Event and Condition included).
        def wait(self, poll_interval=0.2):
            lines = 0
            def tracer(frame, event, arg):
                nonlocal lines
                if event == "line":
                    lines += 1
                    if lines == target:
                        os.kill(os.getpid(), signal.SIGTERM)
                return tracer
            sys.settrace(tracer)
            try:
                return super().wait(poll_interval=0.001)
            finally:
                sys.settrace(None)

    launcher.Stack = TracedStack
    for target in range(1, int(sys.argv[1]) + 1):
        print(target, flush=True)
        assert launcher.main(["--nodes", ""]) == 0
    print("done", flush=True)
""")


def test_sigterm_stops_the_launcher_wherever_it_lands_in_wait():
    """The launcher's own signal handler, with SIGTERM landing at each line of wait() in turn: a handler that
    takes a lock deadlocks at the line where wait() holds it. Killed after the timeout if it hangs."""
    lines = 150  # more than one poll cycle of wait()
    try:
        probe = subprocess.run([sys.executable, "-c", SIGNAL_AT_EVERY_LINE, str(lines)], capture_output=True,
                               text=True, timeout=60)
    except subprocess.TimeoutExpired as timeout:
        last = (timeout.stdout or b"").decode().split()[-1:]
        pytest.fail(f"the launcher hung with SIGTERM landing at line {last} of wait()")
    assert probe.stdout.split()[-1] == "done", probe.stderr[-2000:]


def node_pids(launcher: subprocess.Popen) -> dict[str, int]:
    """The node processes the launcher started, once its node is up ("[name] ... publishing at")."""
    for line in launcher.stdout:
        if line.startswith("[assembly_state]") and "publishing at" in line:
            break
    return {pid: parent for pid, parent in _parents().items() if parent == launcher.pid}


def gone(pid: int) -> bool:
    """Ended (or a zombie waiting for its new parent to collect it)."""
    reap([pid], timeout=0.0)
    return pid not in _parents()


@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGHUP])
def test_the_nodes_never_outlive_the_launcher(params, signum):
    """Old: a launcher ended by SIGKILL, or by SIGHUP (its terminal closed), left its nodes running headless
    (hv_driver included), 236 s later still. A SIGHUP is now a clean stop; after a SIGKILL the kernel sends each
    node SIGTERM (its parent-death signal), which stops it as a Ctrl-C would."""
    launcher = launch("--nodes", "assembly_state", "--params", str(params))
    nodes = node_pids(launcher)
    assert len(nodes) == 1
    launcher.send_signal(signum)
    rest = launcher.stdout.read()
    launcher.wait()
    wait_for(lambda: all(gone(pid) for pid in nodes), what="the node to end with its launcher")
    if signum == signal.SIGHUP:
        assert launcher.returncode == 0 and "launcher: stopped (assembly_state=0)" in rest, rest

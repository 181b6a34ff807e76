"""Stack launcher: nodes as processes reachable over ROS, prefixed output, clean stop on SIGTERM and SIGHUP
(wherever the signal lands), nodes that end with a killed launcher, non-zero exit when a node dies, SIGKILL for
a node that ignores SIGINT; a hostile stack or parameter file is one line; a node's --help is its usage."""
import io
import os
import re
import signal
import subprocess
import sys
import textwrap

import pytest
import rclpy
from crafted_yaml import BILLION_LAUGHS
from processes import _parents, reap
from ros_testing import Inbox, wait_for
from softblock_interfaces.msg import Assembly

from softblock_ros.launcher import NodeDied, Stack, main
from softblock_ros.parameters import node_schema
from softblock_ros.qos import LATCHED
from softblock_ros.stack import load_stack

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


@pytest.mark.parametrize("content, problem", [
    (BILLION_LAUGHS, r"stack.yaml: invalid YAML: line 1, column \d+: anchors and aliases"),
    ("namespace: ''\nnodes:\n\t- name: planner\n", r"stack.yaml: invalid YAML: line 3, column 1: found character '\\t'"),
    ("[" * 100 + "]" * 100, r"stack.yaml: invalid YAML: line 1, column 33: nested deeper than 32 levels"),
    ("# padding\n" * 7000, r"stack.yaml: larger than 65536 bytes")])
def test_a_hostile_stack_file_is_one_line_and_exit_2(tmp_path, content, problem):
    """Old: 412 bytes of aliases hung the launcher (killed at 60 s, or MemoryError at 2.2 GB); a tab was a
    traceback. In a child with bounded memory and time."""
    stack = tmp_path / "stack.yaml"
    stack.write_text(content)
    result = bounded_launch(["--stack", str(stack)])
    assert result.returncode == 2, result.stderr[-2000:]
    assert re.fullmatch(rf"launcher: \S*{problem}[^\n]*\n", result.stderr), result.stderr[-2000:]


def bounded_launch(args) -> subprocess.CompletedProcess:
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30)); "
            "from softblock_ros.launcher import main; sys.exit(main(sys.argv[1:]))")
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=60)


def test_a_stack_file_that_is_a_device_or_a_fifo_is_refused_without_reading(tmp_path):
    """Old: --stack /dev/zero ended in MemoryError after 5.6 s; a FIFO hung the launcher."""
    fifo = tmp_path / "stack.yaml"
    os.mkfifo(fifo)
    for path in ("/dev/zero", str(fifo)):
        result = bounded_launch(["--stack", path])
        assert (result.returncode, result.stderr) == (2, f"launcher: {path}: not a regular file\n")


@pytest.mark.parametrize("content, problem", [
    ("assembly_state: &a\n  ros__parameters: {frame_id: x}\nplanner: *a\n", "anchors and aliases"),
    ("assembly_state:\n  ros__parameters:\n    frame_id: [unclosed\n", "invalid YAML: line 4, column 1"),
    ("- assembly_state\n", "not a parameter file: expected <node name>: {ros__parameters: {...}}"),
    ("assembly_state:\n  ros__parameters:\n    frame_id:\n", "line 3: parameter frame_id has no value"),
    ("assembly_state:\n  ros__parameters:\n    x: [1, \"a\"]\n", "line 3: parameter x: a list of mixed types"),
    ("assembly_state:\n  ros__parameters: 5\n", "ros__parameters must be a mapping of parameter names to values"),
    ("assembly_state:\n  frame_id: x\n", "expected exactly one key, ros__parameters")])
def test_a_bad_parameter_file_is_one_line_from_the_launcher_and_from_a_node(tmp_path, content, problem):
    """Old: rclpy parsed it and printed a 20-line traceback (from every node of the stack); the last four passed
    the check and still ended in rclpy.init's traceback."""
    params = tmp_path / "params.yaml"
    params.write_text(content)
    assert main(["--nodes", "assembly_state", "--params", str(params)]) == 2
    node = subprocess.run([sys.executable, "-m", "softblock_ros.assembly_state_node", "--ros-args", "--params-file",
                           str(params)], capture_output=True, text=True, timeout=120)
    assert node.returncode == 1 and "Traceback" not in node.stderr, node.stderr[-3000:]
    assert re.fullmatch(rf"\[FATAL\] \[assembly_state\]: cannot start: .*params.yaml: [^\n]*{re.escape(problem)}"
                        r"[^\n]*\n", node.stderr), node.stderr


@pytest.mark.parametrize("arguments, problem", [
    (["-r", "__ns:=a b"], "cannot start: -r __ns:='a b': expected a namespace such as /robot1"),
    (["-r", "__ns:=/a/"], "cannot start: -r __ns:='/a/': expected a namespace such as /robot1"),
    (["-p", "not_a_rule"], "cannot start: rcl refused the arguments: failed to initialize rcl: Couldn't parse "
                           "parameter override rule: '-p not_a_rule'")])
def test_arguments_rcl_refuses_end_a_node_with_one_line(arguments, problem):
    """Old: rclpy.init's traceback (an invalid namespace, any argument rcl refuses), or the node's creation's
    (a trailing '/'). rcl logs its own one line before ours where it refuses."""
    node = subprocess.run([sys.executable, "-m", "softblock_ros.assembly_state_node", "--ros-args", *arguments],
                          capture_output=True, text=True, timeout=120)
    assert node.returncode == 1 and "Traceback" not in node.stderr, node.stderr[-3000:]
    assert re.search(rf"^\[FATAL\] \[assembly_state\]: {re.escape(problem)}[^\n]*\n\Z", node.stderr, re.MULTILINE), \
        node.stderr
    assert len(node.stderr.splitlines()) <= 2, node.stderr


def test_the_launcher_refuses_a_namespace_rcl_refuses(capsys):
    assert main(["--nodes", "planner", "--namespace", "a b"]) == 2
    assert capsys.readouterr().err == ("launcher: namespace='a b': expected \"\" (none) or a namespace such as /robot1 "
                                       "(letters, digits and '_' after each '/')\n")


# Every node is asked once; the two spellings, which reach the one check (runner._asks_for_help), alternate.
@pytest.mark.parametrize("node, flag", [(node, ("--help", "-h")[index % 2])
                                        for index, node in enumerate(load_stack().nodes)],
                         ids=lambda value: getattr(value, "name", value))
def test_help_prints_the_nodes_parameters_and_starts_nothing(node, flag):
    """Old: the nodes ignored --help and started (an HV driver among them); every node of the stack is asked."""
    result = subprocess.run([sys.executable, "-m", node.module, *node.arguments, flag], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.startswith("usage: ") and f"\nparameters of node {node.name}:\n" in result.stdout
    first = node_schema(node.name)[0].name
    assert re.search(rf"^  {first} \(default ", result.stdout, re.MULTILINE), result.stdout
    assert result.stderr == ""  # nothing started, nothing logged

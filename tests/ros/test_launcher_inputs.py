"""What the launcher and the nodes refuse to start with, in one line and without starting anything: a hostile
stack or parameter file, arguments rcl refuses, a namespace rcl refuses; a node's --help is its usage. (Split from
test_launcher.py so that the two run on different workers.)"""
import os
import re
import subprocess
import sys

import pytest
from crafted_yaml import BILLION_LAUGHS

from softblock_ros.launcher import main
from softblock_ros.parameters import node_schema
from softblock_ros.stack import load_stack

pytestmark = pytest.mark.integration


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


@pytest.mark.parametrize("flag", ["--help", "-h"])
@pytest.mark.parametrize("node", load_stack().nodes, ids=lambda node: node.name)
def test_help_prints_the_nodes_parameters_and_starts_nothing(node, flag):
    """Old: the nodes ignored --help and started (an HV driver among them); every node of the stack is asked."""
    result = subprocess.run([sys.executable, "-m", node.module, *node.arguments, flag], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.startswith("usage: ") and f"\nparameters of node {node.name}:\n" in result.stdout
    first = node_schema(node.name)[0].name
    assert re.search(rf"^  {first} \(default ", result.stdout, re.MULTILINE), result.stdout
    assert result.stderr == ""  # nothing started, nothing logged

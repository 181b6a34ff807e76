"""Parameter files (--params-file) are checked before rcl reads them: what the check passes, rcl's own parser reads
(rcl_parse_arguments, called here in-process as rclpy.init calls it); what rcl would refuse from inside rclpy.init
with a traceback, the check refuses in one line naming the file, the line and the problem."""
import pytest
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.utilities import remove_ros_args
from softblock_config import config_file

from softblock_ros.parameter_files import check_parameter_file

pytestmark = pytest.mark.fast

NODE = "assembly_state:\n  ros__parameters:\n"


def rcl_reads(path) -> bool:
    try:
        remove_ros_args(["node", "--ros-args", "--params-file", str(path)])
    except rclpy_implementation.RCLError:
        return False
    return True


@pytest.mark.parametrize("content, problem", [
    (NODE + "    frame_id:\n", "line 3: parameter frame_id has no value (empty, ~ or null)"),
    (NODE + "    x: [1, \"a\"]\n", "line 3: parameter x: a list of mixed types (integer, string)"),
    (NODE + "    x: [1, 2.5]\n", "line 3: parameter x: a list of mixed types (double, integer)"),
    (NODE + "    x: [09, b]\n", "line 3: parameter x[0]: '09' is not plainly a number, a bool or a word"),
    (NODE + "    x: [1, 1e5]\n", "line 3: parameter x[1]: '1e5' is not plainly a number"),
    (NODE + "    x: [a, y]\n", "line 3: parameter x: a list of mixed types (bool, string)"),
    (NODE + "    x: |\n", "line 3: parameter x has no value"),
    (NODE + "    x: {}\n    y: 1\n", "line 3: parameter group x: empty; leave it out"),
    ("assembly_state:\n  ros__parameters: 5\n", "line 2: node 'assembly_state': ros__parameters must be a mapping"),
    ("assembly_state:\n  frame_id: x\n", "line 2: node 'assembly_state': expected exactly one key, ros__parameters"),
    (NODE + "    frame_id: x\n  other: 3\n", "found ['ros__parameters', 'other']"),
    ("assembly_state: 5\n", "line 1: node 'assembly_state': expected exactly one key, ros__parameters, holding the "
                            "parameters; found a value"),
    ("1node:\n  ros__parameters:\n    x: 1\n", "line 2: node name '1node': expected name, namespace/name"),
    ("no-de:\n  ros__parameters:\n    x: 1\n", "node name 'no-de'"),
    (NODE + "    x: 1\n  ros__parameters:\n    y: 1\n", "found ['ros__parameters', 'ros__parameters']"),
])
def test_a_file_rcl_refuses_is_refused_in_one_line(tmp_path, content, problem):
    """Old: each passed the check; the node then ended in rclpy.init with an 18-line traceback."""
    path = tmp_path / "params.yaml"
    path.write_text(content)
    assert not rcl_reads(path)  # the case is real
    with pytest.raises(ValueError) as refusal:
        check_parameter_file(path)
    message = str(refusal.value)
    assert message.startswith(f"{path}: ") and problem in message and "\n" not in message, message


@pytest.mark.parametrize("content", [
    NODE + "    frame_id: base\n    rate: 10.0\n    names: [a, 'b c', \"1\"]\n    gains: [1.0, .5, -2., 1.5e-3]\n"
           "    flags: [yes, no, true]\n    ids: [1, -2, 30]\n    empty: ''\n    none: []\n",
    "/**:\n  ros__parameters:\n    use_sim_time: true\n/robot1/planner:\n  ros__parameters:\n    a.b: 1\n"
    "    group:\n      x: [.inf, 1.0]\n",
    "ns/node:\n  ros__parameters: {}\n"])
def test_a_file_rcl_reads_passes(tmp_path, content):
    path = tmp_path / "params.yaml"
    path.write_text(content)
    check_parameter_file(path)
    assert rcl_reads(path)


@pytest.mark.parametrize("name", ["hv_driver.yaml", "sequencer.yaml", "camera.yaml"])
def test_the_shipped_parameter_files_pass_and_rcl_reads_them(name):
    check_parameter_file(config_file(name))
    assert rcl_reads(config_file(name))

"""The stack description (config/stack.yaml): its checks, the launcher's commands from it, and the ros2 launch
file written against it (launch is not on PyPI: the file runs here against stand-ins that record its actions)."""
import ast
import importlib.util
import runpy
import shutil
import sys
import types
from pathlib import Path

import pytest
import yaml
from softblock_config import config_file

from softblock_ros.launcher import Stack
from softblock_ros.stack import load_stack

pytestmark = pytest.mark.fast

PACKAGE = Path(__file__).resolve().parents[2] / "ros_ws" / "src" / "softblock_ros"


def console_scripts() -> dict[str, str]:
    """name -> 'module:function' from softblock_ros's setup.py (read, not run)."""
    tree = ast.parse((PACKAGE / "setup.py").read_text())
    entries = next(node for node in ast.walk(tree) if isinstance(node, ast.Dict)
                   and any(isinstance(k, ast.Constant) and k.value == "console_scripts" for k in node.keys))
    scripts = ast.literal_eval(entries.values[0])
    return dict(line.replace(" ", "").split("=") for line in scripts)


def test_the_shipped_stack_names_real_modules_executables_and_parameter_files():
    stack = load_stack()
    assert stack.names == ("hv_driver", "assembly_state", "planner", "sim_arm", "sim_camera", "estimator", "sequencer",
                           "recorder", "foxglove_bridge")
    scripts = console_scripts()
    for spec in stack.nodes:
        assert spec.executable in scripts, spec
        assert importlib.util.find_spec(spec.module) is not None, spec
        assert all(path.is_file() and path.parent == config_file() for path in spec.parameters)
    assert [p.name for p in stack.node("hv_driver").parameters] == ["hv_driver.yaml"]
    assert stack.node("planner").niceness == 10


def write_stack(tmp_path, **node):
    (tmp_path / "p.yaml").write_text("x:\n  ros__parameters: {}\n")
    entry = {"name": "a", "module": "m", "executable": "e", **node}
    path = tmp_path / "stack.yaml"
    path.write_text(yaml.safe_dump({"namespace": "", "nodes": [entry]}))
    return path


@pytest.mark.parametrize("node, message", [
    ({"nicenes": 3}, r"nodes\[0\]=\['nicenes'\]: unknown key"),
    ({"niceness": 25}, r"nodes\[0\].niceness=25: an integer 0..19"),
    ({"niceness": True}, r"nodes\[0\].niceness=True"),
    ({"parameters": ["../stack.yaml"]}, r"nodes\[0\].parameters='stack.yaml': a parameter file in"),
    ({"parameters": ["missing.yaml"]}, r"nodes\[0\].parameters='missing.yaml'"),
    ({"module": ""}, r"nodes\[0\].module='': a non-empty string"),
    ({"optional": "yes"}, r"nodes\[0\].optional='yes': true or false"),
])
def test_a_bad_stack_file_is_refused_naming_the_field(tmp_path, node, message):
    with pytest.raises(ValueError, match=message):
        load_stack(write_stack(tmp_path, **node))


@pytest.mark.parametrize("namespace", ["a b", "robot1", "/a/", "/a//b", "/a__b", "/1a", "/a-b", 5])
def test_a_namespace_rcl_refuses_is_refused_with_the_stack_file_and_the_launcher_option(tmp_path, namespace):
    """Old: load_stack took namespace 'a b', and every node of the stack then ended in rcl's traceback."""
    path = tmp_path / "stack.yaml"
    path.write_text(yaml.safe_dump({"namespace": namespace, "nodes": [{"name": "a", "module": "m", "executable": "e"}]}))
    with pytest.raises(ValueError, match=rf"stack.yaml: namespace={namespace!r}: expected \"\" \(none\) or a "
                                         r"namespace such as /robot1"):
        load_stack(path)
    if isinstance(namespace, str):
        with pytest.raises(ValueError, match=rf"^namespace={namespace!r}: expected"):
            Stack(nodes=["planner"], namespace=namespace)


@pytest.mark.parametrize("namespace", ["", "/robot1", "/lab/robot_1"])
def test_a_namespace_rcl_takes_is_kept(tmp_path, namespace):
    path = tmp_path / "stack.yaml"
    path.write_text(yaml.safe_dump({"namespace": namespace, "nodes": [{"name": "a", "module": "m", "executable": "e"}]}))
    assert load_stack(path).namespace == namespace == Stack(nodes=["planner"], namespace=namespace).namespace


def test_an_oversized_or_malformed_stack_file_is_refused_before_use(tmp_path):
    path = tmp_path / "stack.yaml"
    path.write_text("nodes: []\n" + "#" * 70000)
    with pytest.raises(ValueError, match="larger than 65536 bytes"):
        load_stack(path)
    path.write_text("nodes: []\n")
    with pytest.raises(ValueError, match="nodes=\\[\\]: a non-empty list"):
        load_stack(path)
    path.write_text("nodes: [{name: a, module: m, executable: e}, {name: a, module: m, executable: e}]\n")
    with pytest.raises(ValueError, match="unique"):
        load_stack(path)


def test_the_launcher_gives_each_node_its_stack_files_then_the_extra_params(tmp_path):
    extra = tmp_path / "extra.yaml"
    extra.write_text("{}\n")
    command = Stack(nodes=["hv_driver"], params=extra, namespace="/r1").command("hv_driver")
    assert command[1:] == ["-m", "softblock_ros.hv_driver_node", "--ros-args",
                           "--params-file", str(config_file("hv_driver.yaml")), "--params-file", str(extra),
                           "-r", "__ns:=/r1"]
    assert Stack(nodes=["recorder"]).command("recorder")[1:] == ["-m", "softblock_ros.recording", "record"]
    with pytest.raises(ValueError, match="unknown nodes \\['nope'\\]"):
        Stack(nodes=["nope"])


def test_an_optional_node_starts_only_when_named():
    stack = load_stack()
    assert stack.node("foxglove_bridge").optional and not stack.node("recorder").optional
    assert Stack().nodes == [name for name in stack.names if name != "foxglove_bridge"]
    assert Stack(nodes=["hv_driver", "foxglove_bridge"]).nodes == ["hv_driver", "foxglove_bridge"]


class Recorded:
    """Stand-in for a launch action or substitution: keeps its arguments."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class SetEnvironment(Recorded):
    """Stand-in for launch.actions.SetEnvironmentVariable."""


@pytest.fixture
def launch_stand_ins(monkeypatch, tmp_path):
    """launch / launch_ros stand-ins and an ament share folder holding the installed config files."""
    share = tmp_path / "share" / "softblock_ros"
    shutil.copytree(config_file(), share / "config", ignore=shutil.ignore_patterns("*.py", "__pycache__"))
    modules = {
        "launch": {"LaunchDescription": lambda actions: list(actions)},
        "launch.actions": {"DeclareLaunchArgument": Recorded, "SetEnvironmentVariable": SetEnvironment},
        "launch.substitutions": {"LaunchConfiguration": Recorded},
        "launch_ros.actions": {"Node": Recorded},
    }
    for name, attributes in modules.items():
        monkeypatch.setitem(sys.modules, name, types.SimpleNamespace(**attributes))
    monkeypatch.setitem(sys.modules, "launch_ros", types.SimpleNamespace())
    index = types.SimpleNamespace(get_package_share_directory=lambda package: str(tmp_path / "share" / package))
    monkeypatch.setitem(sys.modules, "ament_index_python.packages", index)
    return share


def test_the_launch_file_starts_every_node_of_the_stack_as_described(launch_stand_ins, monkeypatch):
    monkeypatch.delenv("ROS_AUTOMATIC_DISCOVERY_RANGE", raising=False)
    launch_file = runpy.run_path(str(PACKAGE / "launch" / "softblock.launch.py"))
    argument, *actions = launch_file["generate_launch_description"]()
    network = {action.args[0]: action.args[1] for action in actions if isinstance(action, SetEnvironment)}
    assert network["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"  # nothing chose a range: this machine only
    nodes = [action for action in actions if not isinstance(action, SetEnvironment)]
    assert argument.args == ("namespace",) and argument.kwargs["default_value"] == ""
    stack = load_stack()
    assert [n.kwargs["executable"] for n in nodes] == [spec.executable for spec in stack.nodes if not spec.optional]
    by_name = {n.kwargs["name"]: n.kwargs for n in nodes}
    assert by_name["hv_driver"]["parameters"] == [str(launch_stand_ins / "config" / "hv_driver.yaml")]
    assert by_name["planner"]["prefix"] == "nice -n 10" and by_name["hv_driver"]["prefix"] is None
    assert all(n.kwargs["package"] == "softblock_ros" and n.kwargs["namespace"].args == ("namespace",) for n in nodes)

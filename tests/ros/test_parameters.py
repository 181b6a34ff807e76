"""Node parameters: one schema per node, checked at start. The params files, the docs' tables and the declared
parameters agree; a misspelt key, a bad value or an empty channel list stops a node with one line that names
the parameter, the value and what is allowed."""
import math
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import rclpy
import yaml
from rclpy.parameter import Parameter
from softblock_config import config_file

from softblock_ros.parameters import NODE_SCHEMAS, Param, ParameterError, declare, markdown_table, node_schema

pytestmark = pytest.mark.integration

DOCS = Path(__file__).resolve().parents[2] / "docs"
NODE_MODULES = {"hv_driver": "softblock_ros.hv_driver_node", "sequencer": "softblock_ros.sequencer_node",
                "planner": "softblock_ros.planner_node", "sim_arm": "softblock_ros.sim_arm_node",
                "assembly_state": "softblock_ros.assembly_state_node"}


def docs_table(node: str) -> str:
    """The table after ``<!-- parameters of NODE -->`` in docs/*.md (exactly one such marker)."""
    marker = f"<!-- parameters of {node} -->\n"
    found = [text.split(marker, 1)[1] for path in sorted(DOCS.glob("*.md"))
             if marker in (text := path.read_text())]
    assert len(found) == 1, f"docs/*.md should hold one parameter table of {node}, found {len(found)}"
    return "\n".join(re.match(r"((?:\|.*\n?)+)", found[0]).group(1).strip().splitlines())


@pytest.mark.parametrize("node", NODE_SCHEMAS)
def test_the_docs_table_of_each_node_is_its_declared_schema(node):
    assert docs_table(node) == markdown_table(node_schema(node)), (
        f"regenerate the table with `python -m softblock_ros.parameters` and paste it after the {node} marker")


@pytest.mark.parametrize("node", NODE_SCHEMAS)
def test_a_description_that_names_another_parameter_names_one_of_its_node(node):
    names = {param.name for param in node_schema(node)}
    named = {(param.name, other) for param in node_schema(node)
             for other in re.findall(r"\bthe ([a-z_]+) parameter\b", param.description)}
    assert not {pair for pair in named if pair[1] not in names}, f"{node}: descriptions name unknown parameters {named}"


def check_parameter_sections(document: dict, where: str) -> int:
    """Check every node section of a parameter file against the node's schema; returns how many there were."""
    sections = {node: body["ros__parameters"] for node, body in document.items()
                if isinstance(body, dict) and "ros__parameters" in body}
    for node, values in sections.items():
        schema = {param.name: param for param in node_schema(node)}
        assert set(values) <= set(schema), f"{where}: {sorted(set(values) - set(schema))} not declared by {node}"
        for name, value in values.items():
            schema[name].check(value)
    return len(sections)


@pytest.mark.parametrize("path", sorted(config_file().glob("*.yaml")), ids=lambda p: p.name)
def test_every_key_of_the_shipped_parameter_files_is_a_valid_declared_parameter(path):
    sections = check_parameter_sections(yaml.safe_load(path.read_text()), path.name)
    if path.name in ("hv_driver.yaml", "sequencer.yaml"):
        assert sections, path


def test_the_sequencer_waits_for_a_silent_driver_as_long_as_the_driver_waits_for_a_silent_client():
    # A loaded host, or a DDS write held up by a stopped reader, left the demo's driver silent for 1.2 s, and a
    # 1 s state timeout called the driver lost and aborted the grasp.
    def default(node, name):
        return next(param.default for param in node_schema(node) if param.name == name)

    def shipped(node, name):
        return yaml.safe_load(config_file(f"{node}.yaml").read_text())[node]["ros__parameters"][name]

    assert default("sequencer", "state_timeout_s") >= default("hv_driver", "heartbeat_timeout_s")
    assert shipped("sequencer", "state_timeout_s") >= shipped("hv_driver", "heartbeat_timeout_s")


DOCS_PARAMETER_BLOCKS = [(path.name, block) for path in sorted(DOCS.glob("*.md"))
                         for block in re.findall(r"```yaml\n(.*?)```", path.read_text(), re.S)
                         if "ros__parameters" in block]


@pytest.mark.parametrize("page, block", DOCS_PARAMETER_BLOCKS, ids=[page for page, _ in DOCS_PARAMETER_BLOCKS])
def test_every_parameter_file_shown_in_the_docs_is_valid(page, block):
    assert check_parameter_sections(yaml.safe_load(block), page)


@pytest.fixture
def make_node(ros_context):
    made = []

    def make(overrides=()):
        node = rclpy.create_node("parameter_test", context=ros_context,
                                 parameter_overrides=[Parameter(n, value=v) for n, v in overrides])
        made.append(node)
        return node
    yield make
    for node in made:
        node.destroy_node()


SCHEMA = (Param("max_voltage_v", 3000.0, "hard maximum", "V", 1.0, 10000.0),
          Param("channel_names", ["front"], "names", kind=str, size=(1, 16)),
          Param("baudrate", 9600, "baud", low=1200, high=921600, kind=int),
          Param("backend", "sim", "backend", kind=str, choices=("sim", "serial")))


def test_declare_returns_checked_values_and_declares_them_read_only(make_node):
    node = make_node([("max_voltage_v", 2000)])  # an integer for a float parameter
    values = declare(node, SCHEMA)
    assert values["max_voltage_v"] == 2000.0 and isinstance(values["max_voltage_v"], float)
    assert node.get_parameter("max_voltage_v").value == 2000.0
    assert node.describe_parameter("max_voltage_v").read_only
    assert node.describe_parameter("max_voltage_v").floating_point_range[0].to_value == 10000.0


@pytest.mark.parametrize("overrides, message", [
    ([("max_volatge_v", 100.0)], "unknown parameter(s) max_volatge_v for node parameter_test; known: backend, "),
    ([("max_voltage_v", 20000.0)], "parameter max_voltage_v=20000.0 refused: allowed 1..10000 V"),
    ([("max_voltage_v", "high")], "parameter max_voltage_v='high' refused: must be a float (1..10000 V)"),
    ([("channel_names", [])], "parameter channel_names=[] refused: give 1..16 item(s)"),
    ([("baudrate", 9600.5)], "parameter baudrate=9600.5 refused: must be a int (1200..921600)"),
    ([("backend", "usb")], "parameter backend='usb' refused: allowed one of sim, serial"),
])
def test_a_bad_parameter_is_one_line_naming_it_and_nothing_is_declared(make_node, overrides, message):
    node = make_node(overrides)
    with pytest.raises(ParameterError) as raised:
        declare(node, SCHEMA)
    assert str(raised.value).startswith(message) and "\n" not in str(raised.value)
    assert not node.has_parameter("max_voltage_v")


def test_infinity_is_accepted_only_where_the_range_reaches_it(make_node):
    schema = SCHEMA + (Param("watchdog_timeout_s", 2.0, "watchdog timeout; .inf = off", "s", 0.05, math.inf),)
    assert declare(make_node([("watchdog_timeout_s", math.inf)]), schema)["watchdog_timeout_s"] == math.inf
    with pytest.raises(ParameterError, match=r"parameter max_voltage_v=inf refused: allowed 1\.\.10000 V"):
        declare(make_node([("max_voltage_v", math.inf)]), schema)
    with pytest.raises(ParameterError, match=r"parameter watchdog_timeout_s=-inf refused: allowed 0\.05\.\.inf s"):
        declare(make_node([("watchdog_timeout_s", -math.inf)]), schema)


def start_node(node: str, params_text: str, tmp_path, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """Run a node process with a params file; it must exit by itself (killed with its group on timeout)."""
    params = tmp_path / "params.yaml"
    params.write_text(params_text)
    process = subprocess.Popen([sys.executable, "-m", NODE_MODULES[node], "--ros-args", "--params-file", str(params)],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, process_group=0,
                               env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        output, _ = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        output, _ = process.communicate()
        pytest.fail(f"{node} did not stop on a bad parameter within {timeout:g} s; output:\n{output[-2000:]}")
    return subprocess.CompletedProcess(process.args, process.returncode, output, "")


@pytest.mark.parametrize("node, section, expected", [
    ("hv_driver", "max_volatge_v: 100.0", "unknown parameter(s) max_volatge_v for node hv_driver"),
    ("hv_driver", "max_voltage_v: 20000", "parameter max_voltage_v=20000 refused: allowed 1..10000 V"),
    ("hv_driver", "channel_names: []", "parameter channel_names=[] refused: give 1..16 item(s)"),
    ("sequencer", "voltage_ceiling_v: -5.0", "parameter voltage_ceiling_v=-5.0 refused: allowed 0..10000 V"),
    ("sim_arm", "initial_position: [0.1, 0.2]", "parameter initial_position=[0.1, 0.2] refused: give exactly 3"),
])
def test_a_node_started_with_a_bad_parameter_exits_with_one_line_and_no_traceback(tmp_path, node, section, expected):
    result = start_node(node, f"{node}:\n  ros__parameters:\n    autostart: false\n    {section}\n"
                        if node == "hv_driver" else f"{node}:\n  ros__parameters:\n    {section}\n", tmp_path)
    assert result.returncode == 1, result.stdout
    assert expected in result.stdout and "Traceback" not in result.stdout, result.stdout
    assert len([line for line in result.stdout.splitlines() if line.strip()]) == 1, result.stdout


def test_an_integer_for_a_float_parameter_starts_the_node(tmp_path):
    params = "hv_driver:\n  ros__parameters:\n    autostart: false\n    max_voltage_v: 2500\n"
    (tmp_path / "params.yaml").write_text(params)
    process = subprocess.Popen([sys.executable, "-m", NODE_MODULES["hv_driver"], "--ros-args", "--params-file",
                                str(tmp_path / "params.yaml")], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True, process_group=0)
    try:
        with pytest.raises(subprocess.TimeoutExpired):  # still running: it started
            process.wait(timeout=8.0)
    finally:
        os.killpg(process.pid, signal.SIGINT)
        try:
            output, _ = process.communicate(timeout=20.0)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            output, _ = process.communicate()
    assert "refused" not in output and "Traceback" not in output, output

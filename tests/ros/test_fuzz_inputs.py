"""Fuzzing every service and action input of the non-HV nodes (planner, assembly_state, sequencer, sim_arm)
with messages drawn from their types (message_strategies): each request is answered, a refusal says why
in one line, an accepted one gives sane outputs, and the node keeps serving afterwards. The files the stack
reads are fuzzed too: stack descriptions, parameter files and image headers each load or are refused in one line
(MCAP files: tests/recording/test_fuzz_recording_files.py).

Draws lean toward what the nodes accept (``mostly``), so the searches and moves behind them run too.
`pytest --hypothesis-show-statistics` shows the share of accepted requests and refusal reasons."""
import math
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy
from action_msgs.msg import GoalStatus
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from message_strategies import TEXT, messages
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.parameter import Parameter
from rclpy.utilities import remove_ros_args
from ros_testing import Inbox, call, wait_for
from sensor_msgs.msg import Image
from softblock_interfaces.action import MoveArm, RunSequence
from softblock_interfaces.msg import Assembly, AssemblyState, BlockDesign, Chain, PlacedBlock
from softblock_interfaces.srv import DesignFingers, DesignPath, SetAssembly
from std_msgs.msg import Float64, Header

from crafted_images import png_header
from crafted_yaml import BILLION_LAUGHS, SELF_REFERENCE
from planner.assembly import load_assembly
from planner.contours import load_mask
from planner.table import load_table
from softblock_ros.assembly_state_node import AssemblyStateNode
from softblock_ros.client import ActionClient, ClientError
from softblock_ros.conversions import assembly_msg, image_msg
from softblock_ros.parameter_files import check_parameter_file
from softblock_ros.paths import resolve_path
from softblock_ros.planner_node import PlannerNode
from softblock_ros.qos import LATCHED
from softblock_ros.sequencer_node import SequencerNode
from softblock_ros.sim_arm_node import SimArmNode
from softblock_ros.stack import load_stack

pytestmark = pytest.mark.integration

RCLError = rclpy_implementation.RCLError
FUZZ = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
ANSWER = 20.0  # [s] liveness bound on one answer; answers take milliseconds to a second
TABLE = load_table()
STRAWBERRY = image_msg(load_mask(resolve_path("config/objects/strawberry.png")).astype(np.uint8) * 255)


def mostly(usual, other):
    """Three draws in four from ``usual`` (what a node accepts), the rest from ``other``."""
    return st.one_of(usual, usual, usual, other)


UNIT_QUATERNIONS = st.sampled_from([(0.0, 0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.7071068, 0.0, 0.7071068)])
ANY_NUMBER = st.floats() | st.sampled_from([0.0, -1.0, 1e-300, 1e300])
TIME_BUDGET = mostly(st.floats(0.05, 0.3), st.floats(-1.0, 0.5) | st.sampled_from([0.0, math.inf, math.nan]))
METHOD = mostly(st.sampled_from(["", "exact", "pso"]), st.just("annealing") | TEXT)
NUM_BLOCKS = mostly(st.integers(1, 2), st.integers(0, 255))


@pytest.fixture(scope="module")
def nodes(ros_context, spin, tmp_path_factory):
    sequences = tmp_path_factory.mktemp("sequences")
    (sequences / "laughs.yaml").write_text(BILLION_LAUGHS)
    (sequences / "loop.yaml").write_text(SELF_REFERENCE)
    (sequences / "passwd.yaml").symlink_to("/etc/passwd")
    bomb = tmp_path_factory.mktemp("images") / "bomb.png"
    bomb.write_bytes(png_header(30_000, 30_000))
    planner = PlannerNode(context=ros_context, parameter_overrides=[
        Parameter("max_blocks", value=2), Parameter("default_time_budget_s", value=0.5)])
    assembly_state = AssemblyStateNode(context=ros_context, parameter_overrides=[Parameter("publish_rate_hz", value=20.0)])
    sequencer = SequencerNode(context=ros_context, parameter_overrides=[
        Parameter("sequences_dir", value=str(sequences))])
    arm = SimArmNode(context=ros_context, parameter_overrides=[
        Parameter("max_speed_m_per_s", value=2.0), Parameter("max_acceleration_m_per_s2", value=20.0),
        Parameter("max_angular_speed_rad_per_s", value=10.0),
        Parameter("max_angular_acceleration_rad_per_s2", value=50.0)])
    client = rclpy.create_node("fuzz_client", context=ros_context)
    spin(planner, assembly_state, sequencer, arm, client)
    run_sequence = ActionClient(client, RunSequence, "sequencer/run")
    assert run_sequence.wait_for_server(timeout_sec=30.0)  # a sequencer serves after looking for another one
    return SimpleNamespace(
        bomb=str(bomb),
        design_fingers=client.create_client(DesignFingers, "planner/design_fingers"),
        design_path=client.create_client(DesignPath, "planner/design_path"),
        set_assembly=client.create_client(SetAssembly, "assembly/set"),
        run_sequence=run_sequence,
        move_arm=ActionClient(client, MoveArm, "arm/move"),
        safe_voltage=Inbox(client, Float64, "assembly/safe_voltage", LATCHED),
        assembly_state=Inbox(client, AssemblyState, "assembly/state"),
        arm_pose=Inbox(client, PoseStamped, "arm/pose"))


def next_message(inbox: Inbox):
    """The first message that arrives from now on."""
    inbox.messages.clear()
    return inbox.wait()


def one_line_reason(message: str) -> bool:
    """A short reason, and not "request failed" (the planner's answer when its own code raised: a bug)."""
    return bool(message) and "\n" not in message and len(message) < 500 and not message.startswith("request failed")


def finite(*values) -> bool:
    return all(math.isfinite(v) for v in values)


def sane_chain(chain: Chain) -> bool:
    return bool(chain.blocks) and all(
        1 <= block.design.id <= 84 and finite(block.rotation, block.design.theta0, block.design.safe_voltage)
        for block in chain.blocks)


# --- planner -------------------------------------------------------------------------------------------
@FUZZ
@given(messages(DesignFingers.Request,
                image=mostly(st.just(STRAWBERRY),
                             messages(Image, height=st.integers(0, 8), width=st.integers(0, 8), step=st.integers(0, 8),
                                      encoding=st.sampled_from(["mono8", "8UC1", "rgb8", ""]) | TEXT,
                                      data=st.binary(max_size=64)) | st.just(Image())),
                image_path=st.sampled_from(["", "config/objects/strawberry.png", "/dev/zero", "/etc/passwd",
                                            "config", "../../../etc/shadow"]) | TEXT,
                pixel_size=mostly(st.sampled_from([0.00025, 0.001]), ANY_NUMBER), num_blocks=NUM_BLOCKS,
                num_stiff_top=mostly(st.integers(0, 2), st.integers(0, 255)),
                min_stiff_rod_diameter=mostly(st.just(0.0), ANY_NUMBER), method=METHOD,
                time_budget=TIME_BUDGET, inventory_ids=mostly(st.just([]), st.lists(st.integers(0, 90), max_size=3)),
                inventory_counts=mostly(st.just([]), st.lists(st.integers(0, 3), max_size=3))))
def test_design_fingers_answers_every_request(nodes, request_message):
    reply = call(nodes.design_fingers, request_message, ANSWER)
    event(f"success={reply.success}")
    if reply.success:
        assert sane_chain(reply.left) and sane_chain(reply.right)
        assert finite(reply.left_cost, reply.right_cost, reply.solve_time) and reply.solve_time >= 0
    else:
        assert one_line_reason(reply.message), reply.message


@FUZZ
@given(messages(DesignPath.Request,
                path=st.lists(messages(Point, x=mostly(st.floats(-0.05, 0.05), ANY_NUMBER), y=st.floats(-0.05, 0.05),
                                       z=mostly(st.floats(0.0, 0.05), ANY_NUMBER)), max_size=5),
                num_blocks=NUM_BLOCKS, method=METHOD, time_budget=TIME_BUDGET))
def test_design_path_answers_every_request(nodes, request_message):
    reply = call(nodes.design_path, request_message, ANSWER)
    event(f"success={reply.success}")
    if reply.success:
        assert sane_chain(reply.chain) and finite(reply.cost, reply.solve_time)
    else:
        assert one_line_reason(reply.message), reply.message


def test_an_image_whose_header_claims_900_megapixels_is_refused_in_one_line(nodes):
    """Old: Pillow's DecompressionBombError escaped the planner's checks ("request failed", a bug's answer)."""
    reply = call(nodes.design_fingers, DesignFingers.Request(image_path=nodes.bomb, pixel_size=0.00025,
                                                              num_blocks=2, time_budget=0.5), ANSWER)
    assert not reply.success and one_line_reason(reply.message), reply.message
    assert "its header claims more than" in reply.message


def test_the_planner_still_designs_after_the_fuzzing(nodes):
    request = DesignFingers.Request(image=STRAWBERRY, pixel_size=0.00025, num_blocks=2, time_budget=30.0)
    reply = call(nodes.design_fingers, request, 60.0)
    assert reply.success and sane_chain(reply.left), reply.message


# --- assembly_state ------------------------------------------------------------------------------------
DESIGN_IDS = mostly(st.integers(1, 84), st.integers(0, 65535))
PLACED_BLOCKS = messages(PlacedBlock, design=messages(BlockDesign, id=DESIGN_IDS),
                         rotation=mostly(st.integers(-12, 12).map(lambda k: k * math.pi / 6), st.floats()),
                         serial=st.sampled_from(["", "S-1", "S-2"]) | TEXT,
                         calibration_offset=mostly(st.just(0.0), st.just(0.02) | ANY_NUMBER))
QUATERNIONS = mostly(UNIT_QUATERNIONS.map(lambda q: Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])), messages(Quaternion))
CHAINS = messages(Chain, name=mostly(st.sampled_from(["a", "b"]), st.just("") | TEXT),
                  hv_channel=st.sampled_from(["front", ""]) | TEXT,
                  base_pose=st.builds(Pose, position=mostly(messages(Point, x=st.floats(-1, 1), y=st.floats(-1, 1),
                                                                     z=st.floats(-1, 1)), messages(Point)),
                                      orientation=QUATERNIONS),
                  blocks=mostly(st.lists(PLACED_BLOCKS, min_size=1, max_size=4), st.just([])))


@FUZZ
@given(messages(SetAssembly.Request, assembly=messages(Assembly, name=TEXT, chains=mostly(
    st.lists(CHAINS, min_size=1, max_size=3), st.just([])))))
def test_set_assembly_answers_every_request_and_keeps_predicting(nodes, request_message):
    nodes.safe_voltage.messages.clear()
    reply = call(nodes.set_assembly, request_message, ANSWER)
    event(f"success={reply.success}")
    if reply.success:
        safe_voltage = nodes.safe_voltage.wait()
        assert finite(safe_voltage.data) and safe_voltage.data > 0
    else:
        assert reply.message.startswith("assembly refused: ") and one_line_reason(reply.message), reply.message
    state = next_message(nodes.assembly_state)  # the timer still runs
    assert all(finite(*chain.block_angles) for chain in state.chains)


@pytest.mark.parametrize("field", ["name", "chain", "hv_channel", "serial"])
def test_set_assembly_refuses_a_100000_character_string_by_its_length(nodes, field):
    """Old: a 100,000-character assembly name was accepted, and published with every state."""
    long = "x" * 100_000
    message = assembly_msg(load_assembly(resolve_path("config/assemblies/gripper.yaml")), TABLE)
    if field == "name":
        message.name = long
    elif field == "chain":
        message.chains[0].name = long
    elif field == "hv_channel":
        message.chains[0].hv_channel = long
    else:
        message.chains[0].blocks[0].serial = long
    reply = call(nodes.set_assembly, SetAssembly.Request(assembly=message), ANSWER)
    assert not reply.success and one_line_reason(reply.message) and long not in reply.message
    assert reply.message.startswith("assembly refused: ") and "(100000 characters) is longer than 100" in reply.message


def test_the_assembly_state_node_takes_a_good_assembly_after_the_fuzzing(nodes):
    gripper = assembly_msg(load_assembly(resolve_path("config/assemblies/gripper.yaml")), TABLE)
    assert call(nodes.set_assembly, SetAssembly.Request(assembly=gripper), ANSWER).success
    nodes.assembly_state.messages.clear()
    assert nodes.assembly_state.wait(lambda state: state.assembly_name == "gripper")


# --- actions -------------------------------------------------------------------------------------------
def send(client: ActionClient, goal):
    future = client.send_goal_async(goal)
    return wait_for(future.done, ANSWER, what="the goal response") and future.result()


def result_of(handle, timeout: float = ANSWER):
    future = handle.get_result_async()
    wait_for(future.done, timeout, what="the result")
    return future.result().status, future.result().result


@FUZZ
@given(messages(RunSequence.Goal, sequence=st.sampled_from(["laughs", "loop", "passwd", "missing", "../laughs",
                                                            "/etc/passwd", "", "x" * 200]) | TEXT))
def test_run_sequence_answers_every_goal_without_file_contents(nodes, goal):
    handle = send(nodes.run_sequence, goal)
    assert handle.accepted
    status, result = result_of(handle)
    assert status == GoalStatus.STATUS_ABORTED and result.message.startswith("rejected: ")
    assert one_line_reason(result.message) and "root:" not in result.message, result.message


NEAR = st.floats(-0.05, 0.05)
NEAR_START = st.builds(Point, x=NEAR.map(lambda d: 0.45 + d), y=NEAR, z=NEAR.map(lambda d: 0.3 + d))
FRAMES = mostly(st.sampled_from(["", "base_link"]), st.just("world") | TEXT)


@settings(FUZZ, max_examples=10)
@given(messages(MoveArm.Goal,
                target=messages(PoseStamped,
                                header=st.builds(Header, frame_id=FRAMES),
                                pose=st.builds(Pose, position=mostly(NEAR_START, messages(Point)),
                                               orientation=QUATERNIONS)),
                max_speed=mostly(st.just(0.0), ANY_NUMBER)))
def test_move_arm_answers_every_goal_and_the_pose_stays_finite(nodes, goal):
    handle = send(nodes.move_arm, goal)
    assert handle.accepted
    future = handle.get_result_async()
    try:
        wait_for(future.done, 1.0, what="a short move")
    except ClientError:  # a long move: cancel = brake and hold
        handle.cancel_goal_async()
    status, result = result_of(handle)
    event(f"status={status} {result.message[:30]}")
    p, q = result.final_pose.position, result.final_pose.orientation
    assert finite(p.x, p.y, p.z, q.x, q.y, q.z, q.w)
    assert status in (GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_ABORTED, GoalStatus.STATUS_CANCELED)
    assert result.success == (status == GoalStatus.STATUS_SUCCEEDED) and (result.success or result.message)
    pose = next_message(nodes.arm_pose).pose
    assert finite(pose.position.x, pose.position.y, pose.position.z, pose.orientation.w)


# --- files the stack reads -----------------------------------------------------------------------------
YAML_TEXT = st.text(st.sampled_from("abnmode:-[]{}&*!|>'\"#\t\n ,?%@0.9"), max_size=200) | st.sampled_from([
    BILLION_LAUGHS, SELF_REFERENCE, "nodes:\n\t- name: x\n", "[" * 40 + "]" * 40, "nodes: []\n",
    "namespace: ''\nnodes:\n  - {name: a, module: m, executable: e}\n"])


def one_line_refusal(error: BaseException) -> bool:
    return isinstance(error, ValueError) and "\n" not in str(error) and len(str(error)) < 500


@settings(FUZZ, max_examples=200)
@given(text=YAML_TEXT)
def test_any_stack_file_loads_or_is_refused_in_one_line(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("stack") / "stack.yaml"
    path.write_text(text)
    try:
        load_stack(path)
    except Exception as error:  # noqa: BLE001 - the assertion names what escaped
        assert one_line_refusal(error), repr(error)


# Scalars where PyYAML and rcl differ (rcl types 09 and 1e5 as doubles, y as a bool; ~ and null are no value to
# PyYAML), the shapes rcl refuses (no value, a value beside ros__parameters) and names it refuses.
SCALARS = st.sampled_from(["1", "-2", "09", "0x10", "1e5", "1.5", "1.", ".5", ".inf", "nan", "inf", "y", "yes", "on",
                           "true", "a", "b c", "'a'", '"1"', "''", "~", "null", "", "1:30", "-", ".", "1_000", "!!str 1",
                           "99999999999999999999999", "1e999", "[]", "{}", "{b: 1}"])
VALUES = SCALARS | st.lists(SCALARS, max_size=3).map(lambda items: f"[{', '.join(items)}]")
NAMES = st.sampled_from(["node", "/node", "/ns/node", "ns/node", "/**", "/*/node", "1node", "no-de", "node/", "a.b",
                         "'a b'", "ros__parameters"])
PARAMETER_FILES = st.builds(
    lambda node, key, value, extra: f"{node}:\n  {key}:\n    x: {value}\n{extra}",
    NAMES, st.sampled_from(["ros__parameters"] * 4 + ["params", "ros__parameters: {}\n  other"]), VALUES,
    st.sampled_from(["", "    y: {x: [1, 2]}\n", "  ros__parameters: 5\n", "other: {ros__parameters: {}}\n"]))


def rcl_reads(path) -> bool:
    """Whether rcl's own parser (rcl_parse_arguments, as rclpy.init calls it) reads the parameter file."""
    try:
        remove_ros_args(["node", "--ros-args", "--params-file", str(path)])
    except RCLError:
        return False
    return True


@settings(FUZZ, max_examples=300)
@given(text=YAML_TEXT | YAML_TEXT.map(lambda body: "node:\n  ros__parameters:\n    " + body) | PARAMETER_FILES)
def test_any_parameter_file_passes_or_is_refused_in_one_line_and_rcl_reads_what_passes(tmp_path_factory, text):
    """Old: a file the check passed could still fail rclpy.init with rcl's traceback (a value left empty, a list of
    mixed types, a key beside ros__parameters, ros__parameters: 5)."""
    path = tmp_path_factory.mktemp("params") / "params.yaml"
    path.write_text(text)
    try:
        check_parameter_file(path)
    except Exception as error:  # noqa: BLE001
        event("refused")
        assert one_line_refusal(error), repr(error)
    else:
        event("passed")
        assert rcl_reads(path), text

"""The vertical slice across processes started by the launcher: the HV driver (simulated supply) and the
assembly-state node (the simulated supply on a pty), driven through the custom interfaces: the latched safe voltage becomes the driver's
ceiling (pub/sub, transient_local), an hv/ramp goal (action) raises the front channel, and the predicted
front-finger angles follow the measured voltage; assembly/set (service) lowers the ceiling."""
import io

import numpy as np
import pytest
import rclpy
from ros_testing import Inbox, call, wait_for
from waiting import GENEROUS_S
from softblock_interfaces.action import RampChannel
from softblock_interfaces.msg import AssemblyState, HvState
from softblock_interfaces.srv import SetAssembly
from std_msgs.msg import Float64

from hv_driver.config import ChannelConfig
from planner.assembly import Assembly, Chain, PlacedBlock, load_assembly
from planner.table import load_table
from softblock_ros.client import ActionClient
from softblock_ros.hv_control import HvControl
from softblock_ros.conversions import assembly_msg, safe_voltage
from softblock_ros.launcher import Stack
from softblock_ros.paths import resolve_path
from softblock_ros.qos import LATCHED

pytestmark = pytest.mark.integration

NAMESPACE = "/slice"  # apart from in-process nodes of other test modules
TABLE = load_table()
GRIPPER = load_assembly(resolve_path("config/assemblies/gripper.yaml"))
TARGET = 1000.0  # [V]


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    params = tmp_path_factory.mktemp("slice") / "params.yaml"
    # the simulated supply on a pty (the driver's serial path, as with real hardware); a hard maximum above every
    # design's safe voltage (3.2-3.4 kV), so that the assembly's is the ceiling
    params.write_text("/**/hv_driver:\n  ros__parameters:\n    backend: sim\n    sim_link: pty\n"
                      "    slew_rate_v_per_s: 5000.0\n"
                      "    link_timeout_s: 2.0\n    max_voltage_v: 5000.0\n")
    output = io.StringIO()
    with Stack(nodes=["hv_driver", "assembly_state"], params=params, namespace=NAMESPACE, output=output) as stack:
        yield stack
    assert stack.stop() == {"hv_driver": 0, "assembly_state": 0}, output.getvalue()


@pytest.fixture(scope="module")
def client(ros_context, spin, stack):
    node = rclpy.create_node("slice_client", namespace=NAMESPACE, context=ros_context)
    node.hv_states = Inbox(node, HvState, "hv/state")
    node.assembly_states = Inbox(node, AssemblyState, "assembly/state")
    node.safe_voltages = Inbox(node, Float64, "assembly/safe_voltage", LATCHED)
    node.control = HvControl(node, "slice_client", timeout_s=GENEROUS_S)
    spin(node)
    node.control.claim()
    return node


def latest(inbox, predicate):
    """The first message from now on that satisfies ``predicate``."""
    inbox.messages.clear()
    return inbox.wait(predicate)


def ramp(client, channel, target):
    action = ActionClient(client, RampChannel, "hv/ramp")
    assert action.wait_for_server(timeout_sec=GENEROUS_S)
    sent = action.send_goal_async(client.control.ramp_goal(channel, target))
    goal = wait_for(sent.done) and sent.result()
    assert goal.accepted
    done = goal.get_result_async()
    wait_for(done.done, what=f"the ramp of {channel} to {target} V")
    return done.result().result


def test_the_assembly_safe_voltage_becomes_the_driver_ceiling(client):
    expected = safe_voltage(GRIPPER, TABLE)
    assert client.safe_voltages.wait().data == pytest.approx(expected)
    state = client.hv_states.wait(lambda s: s.channels and all(c.ceiling == pytest.approx(expected) for c in s.channels))
    assert {c.name for c in state.channels} == {"front", "back"}


def test_a_ramp_goal_moves_the_predicted_front_fingers(client):
    at_rest = client.assembly_states.wait(lambda s: s.chains and s.chains[0].voltage < 1.0)
    result = ramp(client, "front", TARGET)
    assert result.success, result.message
    # A ramp has reached its target once the readback is within the mismatch tolerance of it (the driver's
    # contract): how far the simulated output still lags at that moment depends on the host's speed.
    assert result.final_voltage == pytest.approx(TARGET, abs=ChannelConfig.mismatch_tolerance_v)
    moved = latest(client.assembly_states, lambda s: abs(s.chains[0].voltage - TARGET) < 50.0)
    for before, after, chain in zip(at_rest.chains, moved.chains, GRIPPER.chains):
        expected, valid = TABLE.angle_at(list(chain.design_ids), after.voltage)
        np.testing.assert_allclose(after.block_angles, expected)
        assert list(after.block_valid) == valid.tolist()
        if chain.hv_channel == "front":
            assert not np.allclose(after.block_angles, before.block_angles)
        else:
            np.testing.assert_allclose(after.block_angles, before.block_angles)
    assert ramp(client, "front", 0.0).success


def test_a_new_assembly_lowers_the_ceiling(client):
    weakest = min(TABLE.ids, key=lambda i: TABLE.design(int(i)).safe_voltage)
    trunk = Assembly("trunk", (Chain("trunk", "front", (PlacedBlock(int(weakest)), PlacedBlock(57))),))
    try:
        reply = call(client.create_client(SetAssembly, "assembly/set"), SetAssembly.Request(
            assembly=assembly_msg(trunk, TABLE)))
        assert reply.success, reply.message
        ceiling = TABLE.design(int(weakest)).safe_voltage
        latest(client.hv_states, lambda s: s.channels[0].ceiling == pytest.approx(ceiling))
    finally:
        call(client.create_client(SetAssembly, "assembly/set"), SetAssembly.Request(
            assembly=assembly_msg(GRIPPER, TABLE)))

"""Sequencer against the real HV driver node (simulated supply on a pty) and the simulated arm:
the scaled finger grasp succeeds while the sequencer holds control and its heartbeat keeps the driver's
watchdog quiet, and an over-current injected through `hv/inject_fault` mid-sequence ends in the safe state.
How long a gap the watchdog bears is the supervisor's, tested on an injected clock (tests/hv_driver/test_control.py):
a stall of this process, which holds the driver node too, lasts as long as the host makes it and past the node's
keep-alive bound rightly ends in NODE_LOST."""
import pytest
import rclpy
from action_msgs.msg import GoalStatus
from hv_driver.supervisor import DEFAULT_HEARTBEAT_TIMEOUT_S
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from ros_testing import Inbox, call, wait_for
from waiting import GENEROUS_S
from sequence_files import scaled
from softblock_interfaces.action import RunSequence
from softblock_interfaces.msg import HvState, SequenceEvent
from softblock_interfaces.srv import InjectFault
from std_srvs.srv import Trigger

from softblock_ros.client import ActionClient
from softblock_ros.hv_driver_node import HvDriverNode
from softblock_ros.sequencer_node import SequencerNode
from softblock_ros.sim_arm_node import SimArmNode

pytestmark = pytest.mark.integration

RUN_TIMEOUT = 40.0
TIMEOUT_S = DEFAULT_HEARTBEAT_TIMEOUT_S  # the driver's heartbeat and the sequencer's hv/state timeouts: the defaults


@pytest.fixture(scope="module")
def stack(ros_context, spin, tmp_path_factory):
    directory = tmp_path_factory.mktemp("sequences")
    driver = HvDriverNode(context=ros_context, parameter_overrides=[
        Parameter("autostart", value=False), Parameter("slew_rate_v_per_s", value=15_000.0),
        Parameter("heartbeat_timeout_s", value=TIMEOUT_S)])
    sequencer = SequencerNode(context=ros_context, parameter_overrides=[
        Parameter("settle_time_s", value=2.0), Parameter("sequences_dir", value=str(directory)),
        Parameter("state_timeout_s", value=TIMEOUT_S)])
    arm = SimArmNode(context=ros_context, parameter_overrides=[
        Parameter("max_speed_m_per_s", value=2.0), Parameter("max_acceleration_m_per_s2", value=20.0)])
    client = rclpy.create_node("sequencer_hv_test_client", context=ros_context)
    spin(driver, sequencer, arm, client)
    assert driver.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert driver.trigger_activate() == TransitionCallbackReturn.SUCCESS
    stack = {
        "dir": directory,
        "action": ActionClient(client, RunSequence, "sequencer/run"),
        "reset": client.create_client(Trigger, "hv/reset_faults"),
        "inject": client.create_client(InjectFault, "hv/inject_fault"),
        "state": Inbox(client, HvState, "hv/state"),
        "events": Inbox(client, SequenceEvent, "sequencer/events", 100),
    }
    assert stack["action"].wait_for_server(timeout_sec=GENEROUS_S)
    return stack


def start(stack, sequence):
    """Clear faults and send the goal at once (the sequencer claims control of the driver for it)."""
    call(stack["inject"], InjectFault.Request(fault="clear"))
    assert call(stack["reset"], Trigger.Request()).success
    stack["events"].messages.clear()
    future = stack["action"].send_goal_async(RunSequence.Goal(sequence=sequence))
    return wait_for(future.done, what="the goal response") and future.result()


def result_of(handle):
    future = handle.get_result_async()
    wait_for(future.done, RUN_TIMEOUT, what="the sequence result")
    return future.result().status, future.result().result


def all_channels_at_zero(stack) -> HvState:
    stack["state"].messages.clear()
    return stack["state"].wait(lambda msg: all(abs(c.measured_voltage) < 50.0 for c in msg.channels))


def test_finger_grasp_with_the_real_driver(stack):
    handle = start(stack, scaled("finger_grasp", stack["dir"], speed=2.0, slew_rate=15_000.0))
    status, result = result_of(handle)
    assert status == GoalStatus.STATUS_SUCCEEDED and result.success, result.message
    assert len(result.step_names) == 12
    all_channels_at_zero(stack)


def test_injected_over_current_ends_in_the_safe_state(stack):
    handle = start(stack, scaled("finger_grasp", stack["dir"], speed=0.05, slew_rate=15_000.0))
    stack["events"].wait(lambda msg: msg.step_name == "surround_object" and msg.phase == "started")
    assert call(stack["inject"], InjectFault.Request(channel="front", fault="over_current")).success
    status, result = result_of(handle)
    assert status == GoalStatus.STATUS_ABORTED and not result.success
    assert result.failed_step == "surround_object"
    assert "HV fault (front:" in result.message
    state = all_channels_at_zero(stack)
    assert state.channels[[c.name for c in state.channels].index("front")].faults
    failed = stack["events"].wait(lambda msg: msg.phase == "failed")
    assert failed.step_name == "surround_object"

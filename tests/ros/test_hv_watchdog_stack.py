"""The heartbeat watchdog with the quick start's parameters (docs/sequences.md: the launcher with
`--params config/sequencer.yaml`, which has no hv_driver section): it is on, and a SIGKILLed sequencer
holding control at 2.4 kV leaves the output ramped down with HEARTBEAT latched. Switching it off takes
`heartbeat_timeout_s: .inf` and is warned when the driver starts; 0 does not switch it off."""
import io

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from ros_testing import Inbox, call, wait_for
from softblock_interfaces.action import MoveArm, RunSequence
from softblock_interfaces.msg import HvChannelState, HvState
from std_srvs.srv import Trigger

from softblock_config import config_file
from softblock_ros.client import ActionClient, ClientError
from softblock_ros.hv_driver_node import HvDriverNode
from softblock_ros.launcher import Stack
from softblock_ros.parameters import ParameterError

pytestmark = pytest.mark.integration

NAMESPACE = "/watchdog"
QUICK_START_PARAMS = config_file("sequencer.yaml")
STARTUP_TIMEOUT = 60.0  # [s] three node processes on two loaded cores
# Heartbeat timeout (2 s default) + the ramp down from 2.4 kV at 1000 V/s (4.5 s), with room for the load.
RAMP_DOWN_TIMEOUT = 30.0


@pytest.fixture(scope="module")
def stack():
    output = io.StringIO()
    with Stack(nodes=["hv_driver", "sim_arm", "sequencer"], params=QUICK_START_PARAMS, namespace=NAMESPACE,
               output=output) as stack:
        stack.log = output
        yield stack
    codes = stack.stop()
    assert codes["hv_driver"] == 0 and codes["sim_arm"] == 0, output.getvalue()


@pytest.fixture(scope="module")
def client(ros_context, spin, stack):
    node = rclpy.create_node("watchdog_client", namespace=NAMESPACE, context=ros_context)
    node.states = Inbox(node, HvState, "hv/state", 100)
    node.diagnostics = Inbox(node, DiagnosticArray, "/diagnostics")
    node.run = ActionClient(node, RunSequence, "sequencer/run")
    node.arm = ActionClient(node, MoveArm, "arm/move")
    node.reset = node.create_client(Trigger, "hv/reset_faults")
    spin(node)
    return node


def control_values(array: DiagnosticArray) -> dict | None:
    status = next((s for s in array.status if s.name == "hv_driver: control"), None)
    return None if status is None else {kv.key: kv.value for kv in status.values}


def test_the_quick_start_parameters_leave_the_watchdog_on(client):
    values = control_values(client.diagnostics.wait(control_values, STARTUP_TIMEOUT))
    assert values["heartbeat_timeout_s"] == "2.0"


def test_a_sigkilled_sequencer_leaves_the_output_ramped_down_and_heartbeat_latched(stack, client):
    assert client.run.wait_for_server(timeout_sec=STARTUP_TIMEOUT)
    assert client.arm.wait_for_server(timeout_sec=STARTUP_TIMEOUT)  # the sequence's first step moves the arm
    # The nodes' start-up on two loaded cores can starve the simulated supply into a LINK fault: start clean.
    assert call(client.reset, Trigger.Request(), STARTUP_TIMEOUT).success
    client.run.send_goal_async(RunSequence.Goal(sequence="finger_grasp"))
    back = lambda state: next(c for c in state.channels if c.name == "back")  # noqa: E731
    try:
        client.states.wait(lambda s: back(s).measured_voltage > 2350.0, STARTUP_TIMEOUT)
    except ClientError as error:
        pytest.fail(f"{error}; the nodes' output:\n{stack.log.getvalue()[-4000:]}")
    client.diagnostics.messages.clear()
    assert control_values(client.diagnostics.wait(lambda a: (v := control_values(a)) and v["controller"]))[
        "controller"] == "sequencer"
    stack.processes["sequencer"].kill()
    stack.processes["sequencer"].wait(timeout=10.0)
    client.states.messages.clear()
    latched = client.states.wait(lambda s: back(s).faults & HvChannelState.FAULT_HEARTBEAT, RAMP_DOWN_TIMEOUT)
    assert "control of 'sequencer' lapsed: no heartbeat for more than 2 s" in back(latched).fault_text
    safe = client.states.wait(lambda s: back(s).measured_voltage < 50.0 and not back(s).output_enabled,
                              RAMP_DOWN_TIMEOUT)
    assert back(safe).faults & HvChannelState.FAULT_HEARTBEAT
    ramping = [s for s in client.states.messages if back(s).output_enabled and 50.0 < back(s).setpoint < 2300.0
               and back(s).faults & HvChannelState.FAULT_HEARTBEAT]
    assert ramping, "the output was cut instead of ramped down"
    wait_for(lambda: all(abs(c.measured_voltage) < 50.0 for c in client.states.messages[-1].channels),
             what="every channel below 50 V")


def test_switching_the_watchdog_off_takes_inf_and_is_warned_at_start(tmp_path):
    params = tmp_path / "watchdog_off.yaml"
    params.write_text("/**/hv_driver:\n  ros__parameters:\n    heartbeat_timeout_s: .inf\n")
    output = io.StringIO()
    with Stack(nodes=["hv_driver"], params=params, namespace="/watchdog_off", output=output) as stack:
        wait_for(lambda: "configured:" in output.getvalue() or stack.dead(), STARTUP_TIMEOUT, "the driver to start")
    log = output.getvalue()
    assert "[WARN]" in log and "heartbeat watchdog OFF (heartbeat_timeout_s=inf)" in log, log


@pytest.mark.parametrize("timeout", [0.0, -1.0, float("nan"), -float("inf")])
def test_a_zero_negative_or_nan_heartbeat_timeout_is_refused_naming_the_range(ros_context, timeout):
    with pytest.raises(ParameterError, match=rf"parameter heartbeat_timeout_s={timeout!r} refused: allowed 0.05..inf s"):
        HvDriverNode(context=ros_context, parameter_overrides=[Parameter("heartbeat_timeout_s", value=timeout)])

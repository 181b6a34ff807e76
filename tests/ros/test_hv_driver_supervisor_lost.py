"""The HV driver node whose supervisor process died: every client gets a prompt refusal naming the fault
(supervisor_lost): hv/estop, hv/reset_faults, hv/claim_control and a ramp goal; hv/state and /diagnostics show it on
every channel."""
import os
import signal

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from ros_testing import Inbox, call
from softblock_interfaces.action import RampChannel
from softblock_interfaces.msg import HvChannelState, HvState
from std_srvs.srv import Trigger

from softblock_ros.client import ActionClient, ClientError, run_action
from softblock_ros.hv_control import HvControl
from softblock_ros.hv_driver_node import HvDriverNode

pytestmark = pytest.mark.integration

TIMEOUT = 60.0  # [s] for an answer or an event; generous, the host may be loaded
FAULT = "supervisor_lost"
SUCCESS = TransitionCallbackReturn.SUCCESS


def lost_everywhere(state: HvState) -> bool:
    return all(c.faults & HvChannelState.FAULT_SUPERVISOR_LOST for c in state.channels)


def test_after_the_supervisor_process_died_every_client_is_refused_naming_the_fault(ros_context, spin):
    driver = HvDriverNode(context=ros_context, parameter_overrides=[
        Parameter("autostart", value=False), Parameter("slew_rate_v_per_s", value=8000.0)])
    client = rclpy.create_node("supervisor_lost_client", context=ros_context)
    estop, reset = (client.create_client(Trigger, name) for name in ("hv/estop", "hv/reset_faults"))
    control, other = HvControl(client, "sequencer", timeout_s=TIMEOUT), HvControl(client, "operator",
                                                                                 timeout_s=TIMEOUT)
    ramp = ActionClient(client, RampChannel, "hv/ramp")
    states = Inbox(client, HvState, "hv/state", 100)
    diagnostics = Inbox(client, DiagnosticArray, "/diagnostics", 100)
    spin(driver, client)
    assert driver.trigger_configure() == SUCCESS and driver.trigger_activate() == SUCCESS
    try:
        control.claim()
        os.kill(driver._supply.pid, signal.SIGKILL)
        states.wait(lost_everywhere, TIMEOUT)

        for service in (estop, reset):
            reply = call(service, Trigger.Request(), TIMEOUT)
            assert not reply.success and FAULT in reply.message, reply.message
        with pytest.raises(ClientError, match=FAULT):
            other.claim()
        status, result = run_action(ramp, control.ramp_goal("front", 600.0), TIMEOUT, server_timeout=TIMEOUT)
        assert not result.success and FAULT in result.message, result.message

        state = states.wait(lost_everywhere, TIMEOUT)
        assert all("only the supplies' own means still hold" in c.fault_text for c in state.channels)
        report = diagnostics.wait(lambda d: any(FAULT in s.message and s.level == DiagnosticStatus.ERROR
                                                for s in d.status), TIMEOUT)
        assert all(s.level == DiagnosticStatus.ERROR for s in report.status if ": channel " in s.name)
    finally:
        driver.trigger_shutdown()

"""A SIGKILLed HV driver node at 2.4 kV, while the client holding control lives on and keeps beating: its supervisor
process ramps the outputs down (NODE_LOST), and a node restarted on the same supervisor socket takes the supervisor
over and shows the faults latched, the outputs below 50 V and off."""
import os
import shutil
import signal
import sys
import tempfile

import pytest
import rclpy
from processes import start, stop
from ros_testing import Inbox
from softblock_interfaces.action import RampChannel
from softblock_interfaces.msg import HvChannelState, HvState

from softblock_ros.client import ActionClient, run_action
from softblock_ros.hv_control import HvControl

NAMESPACE = "/killed"
TIMEOUT = 60.0  # [s] for a node process to start, a ramp to end, an event to show; the host may be loaded


@pytest.fixture
def supervisor_socket():
    directory = tempfile.mkdtemp(prefix="hv-")
    yield os.path.join(directory, "s.sock")
    shutil.rmtree(directory, ignore_errors=True)


def driver(socket_path: str):
    return start([sys.executable, "-m", "softblock_ros.hv_driver_node", "--ros-args", "-r", f"__ns:={NAMESPACE}",
                  "-p", f"supervisor_socket:={socket_path}", "-p", "slew_rate_v_per_s:=8000.0",
                  "-p", "max_voltage_v:=3000.0"])


def front(state: HvState) -> HvChannelState:
    return next(c for c in state.channels if c.name == "front")


def test_a_killed_driver_node_leaves_every_output_ramped_down_and_latched(ros_context, spin, supervisor_socket):
    client = rclpy.create_node("killed_client", namespace=NAMESPACE, context=ros_context)
    states = Inbox(client, HvState, "hv/state", 100)
    control = HvControl(client, "sequencer", timeout_s=TIMEOUT)  # beats at 10 Hz while it holds control
    ramp = ActionClient(client, RampChannel, "hv/ramp")
    spin(client)
    first = driver(supervisor_socket)
    second = None
    try:
        control.claim()  # and the client lives on, beating, after the node's death
        states.wait(lambda s: front(s).output_enabled, TIMEOUT)
        status, result = run_action(ramp, control.ramp_goal("front", 2400.0), TIMEOUT, server_timeout=TIMEOUT)
        assert result.success, result.message
        os.kill(first.pid, signal.SIGKILL)
        first.wait()
        second = driver(supervisor_socket)  # takes the running supervisor over: same settings, same socket
        states.messages.clear()
        down = states.wait(lambda s: front(s).faults & HvChannelState.FAULT_NODE_LOST
                           and front(s).measured_voltage < 50.0 and not front(s).output_enabled, TIMEOUT)
        assert "HV driver node lost" in front(down).fault_text
        assert all(c.faults & HvChannelState.FAULT_NODE_LOST for c in down.channels)
    finally:
        first.kill()
        if second is not None:
            assert stop(second, TIMEOUT) == 0
    assert not os.path.exists(supervisor_socket)  # the second node's clean stop ended the supervisor

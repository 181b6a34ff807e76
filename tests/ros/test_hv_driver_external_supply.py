"""The HV driver node pointed through its parameters at an external emulator on a pty (backend serial, ports, dialect),
as an outside checker does with its own: a simulated iseg module in a process of its own. The node ramps, and cuts an
arc the emulator shows with a named fault; killed with SIGKILL at 2.4 kV and started again with the same parameters,
it reaches the supervisor that still holds the port (its socket path follows from the node's name, domain and ports)
and finds NODE_LOST latched until a client resets it."""
import os
import signal
import sys

import pytest
import rclpy
from processes import start, stop
from ros_testing import Inbox, call
from softblock_interfaces.action import RampChannel
from softblock_interfaces.msg import HvChannelState, HvState
from std_srvs.srv import Trigger

from sim_fallback.hv_supply_process import SimulatedSupplyProcess
from softblock_ros.client import ActionClient, run_action
from softblock_ros.hv_control import HvControl

pytestmark = pytest.mark.integration

NAMESPACE = "/external"
TIMEOUT = 60.0  # [s] for a node process to start, a ramp to end, an event to show; the host may be loaded


@pytest.fixture
def emulator():
    with SimulatedSupplyProcess(channels=2, dialect="iseg-edcp") as supply:
        yield supply


@pytest.fixture
def client(ros_context, spin):
    node = rclpy.create_node("external_client", namespace=NAMESPACE, context=ros_context)
    spin(node)
    return node


def driver(port: str, runtime_dir) -> "subprocess.Popen":  # noqa: F821 (processes.start's Popen)
    """The node as an outside checker starts it: backend serial on the emulator's pty; no supervisor_socket."""
    return start([sys.executable, "-m", "softblock_ros.hv_driver_node", "--ros-args", "-r", f"__ns:={NAMESPACE}",
                  "-p", "backend:=serial", "-p", "dialect:=iseg-edcp", "-p", f"ports:=['{port}']",
                  "-p", "slew_rate_v_per_s:=8000.0", "-p", "max_voltage_v:=3000.0"],
                 env={**os.environ, "XDG_RUNTIME_DIR": str(runtime_dir)})


def front(state: HvState) -> HvChannelState:
    return next(c for c in state.channels if c.name == "front")


def ramp(client, control: HvControl, volts: float) -> None:
    status, result = run_action(ActionClient(client, RampChannel, "hv/ramp"), control.ramp_goal("front", volts),
                                TIMEOUT, server_timeout=TIMEOUT)
    assert result.success, result.message


def test_the_node_on_an_external_emulator_cuts_an_arc_with_a_named_fault(client, emulator, tmp_path):
    states = Inbox(client, HvState, "hv/state", 100)
    control = HvControl(client, "checker", timeout_s=TIMEOUT)
    node = driver(emulator.port, tmp_path)
    try:
        control.claim()
        states.wait(lambda s: front(s).output_enabled, TIMEOUT)
        ramp(client, control, 1500.0)
        emulator.inject("over_current", 0)
        cut = states.wait(lambda s: front(s).faults & HvChannelState.FAULT_OVER_CURRENT, TIMEOUT)
        assert "over_current" in front(cut).fault_text
        states.wait(lambda s: not front(s).output_enabled and front(s).measured_voltage < 50.0, TIMEOUT)
    finally:
        assert stop(node, TIMEOUT) == 0


def test_a_node_killed_at_2_4_kv_and_started_again_reaches_its_surviving_supervisor(client, emulator, tmp_path):
    states = Inbox(client, HvState, "hv/state", 100)
    control = HvControl(client, "sequencer", timeout_s=TIMEOUT)  # lives on, beating, after the node's death
    first = driver(emulator.port, tmp_path)
    second = None
    try:
        control.claim()
        states.wait(lambda s: front(s).output_enabled, TIMEOUT)
        ramp(client, control, 2400.0)
        os.kill(first.pid, signal.SIGKILL)
        first.wait()
        second = driver(emulator.port, tmp_path)  # the supervisor still holds the port: the node must reach it
        states.messages.clear()
        down = states.wait(lambda s: front(s).faults & HvChannelState.FAULT_NODE_LOST
                           and front(s).measured_voltage < 50.0 and not front(s).output_enabled, TIMEOUT)
        assert all(c.faults & HvChannelState.FAULT_NODE_LOST for c in down.channels)
        assert "HV driver node lost" in front(down).fault_text
        operator = HvControl(client, "operator", timeout_s=TIMEOUT)
        operator.claim()
        reply = call(client.create_client(Trigger, "hv/reset_faults"), Trigger.Request(), TIMEOUT)
        assert reply.success, reply.message
        states.wait(lambda s: not any(c.faults for c in s.channels) and front(s).output_enabled, TIMEOUT)
        ramp(client, operator, 600.0)
    finally:
        first.kill()
        if second is not None:
            assert stop(second, TIMEOUT) == 0
    assert not list(tmp_path.glob("softblock-hv/*.sock"))  # the second node's clean stop ended the supervisor

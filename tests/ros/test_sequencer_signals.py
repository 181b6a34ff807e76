"""The sequencer as its own process, stopped by SIGINT or SIGTERM mid-sequence against the simulated HV driver:
its safe stop runs first (every channel ramped back to 0 V, control released, no heartbeat fault), then it exits
with status 0 and no traceback. (Ctrl-C used to shut its ROS context down at once: a 60-line InvalidHandle
traceback, and the voltage came down only through the driver's watchdog.)"""
import signal
import subprocess
import sys

import pytest
import rclpy
from action_msgs.msg import GoalStatus
from processes import start, stop
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from ros_testing import Inbox, wait_for
from sequence_files import scaled
from softblock_interfaces.action import RunSequence
from softblock_interfaces.msg import HvState

from softblock_ros.client import ActionClient
from softblock_ros.hv_driver_node import HvDriverNode
from softblock_ros.sim_arm_node import SimArmNode

NAMESPACE = "/sequencer_signals"
TIMEOUT = 60.0  # [s] liveness bound for a process start, a sequence's stop and the exit


@pytest.fixture(scope="module")
def rig(ros_context, spin, tmp_path_factory):
    directory = tmp_path_factory.mktemp("sequences")
    driver = HvDriverNode(namespace=NAMESPACE, context=ros_context, parameter_overrides=[
        Parameter("autostart", value=False), Parameter("slew_rate_v_per_s", value=15_000.0)])
    arm = SimArmNode(namespace=NAMESPACE, context=ros_context, parameter_overrides=[
        Parameter("max_speed_m_per_s", value=2.0), Parameter("max_acceleration_m_per_s2", value=20.0)])
    client = rclpy.create_node("sequencer_signals_client", namespace=NAMESPACE, context=ros_context)
    spin(driver, arm, client)
    assert driver.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert driver.trigger_activate() == TransitionCallbackReturn.SUCCESS
    return {"dir": directory, "driver": driver, "action": ActionClient(client, RunSequence, "sequencer/run"),
            "state": Inbox(client, HvState, "hv/state")}


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_sequence_runs_the_safe_stop_first_then_exits_cleanly(rig, signum):
    name = scaled("finger_grasp", rig["dir"], speed=0.05, slew_rate=15_000.0)
    log_path = rig["dir"] / f"sequencer_{signum.name}.log"
    with open(log_path, "w") as log_file:  # the node's log goes to stderr
        process = start([sys.executable, "-m", "softblock_ros.sequencer_node", "--ros-args", "-r",
                         f"__ns:={NAMESPACE}", "-p", f"sequences_dir:={rig['dir']}", "-p", "settle_time_s:=2.0"],
                        stdout=subprocess.DEVNULL, stderr=log_file)
    try:
        assert rig["action"].wait_for_server(timeout_sec=TIMEOUT)
        sent = rig["action"].send_goal_async(RunSequence.Goal(sequence=name))
        handle = wait_for(sent.done, TIMEOUT, what="the goal response") and sent.result()
        assert handle.accepted
        rig["state"].messages.clear()
        rig["state"].wait(lambda s: any(c.measured_voltage > 1000.0 for c in s.channels), TIMEOUT)
        result = handle.get_result_async()
        process.send_signal(signum)
        wait_for(result.done, TIMEOUT, what="the sequence's result after the signal")
        assert result.result().status == GoalStatus.STATUS_ABORTED
        assert result.result().result.message.startswith("sequencer stopped: canceled during step")
        assert process.wait(TIMEOUT) == 0
    finally:
        stop(process, timeout=TIMEOUT)
    log = log_path.read_text()
    assert "Traceback" not in log and "InvalidHandle" not in log, log
    assert f"{signum.name}: canceling sequence 'finger_grasp'" in log and f"{signum.name}: shutting down" in log
    rig["state"].messages.clear()
    state = rig["state"].wait(lambda s: all(abs(c.measured_voltage) < 50.0 for c in s.channels), TIMEOUT)
    assert not any(c.faults for c in state.channels), [c.fault_text for c in state.channels]
    snapshot = rig["driver"]._supply.snapshot()
    assert snapshot.controller == "" and snapshot.control_ended == "control released by 'sequencer'"

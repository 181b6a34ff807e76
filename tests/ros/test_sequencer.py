"""Sequencer node through real rclpy action clients, with the simulated arm and a fake HV driver:
the finger grasp succeeds, an HV fault mid-sequence and a cancel both end in the safe state, bad
sequences are refused with a clear message, a second goal is rejected, the legged gait pulses its legs.

The shipped strategies run with their timings scaled down (sequence_files.scaled)."""
import time

import pytest
import rclpy
import yaml
from action_msgs.msg import GoalStatus
from geometry_msgs.msg import PoseStamped
from fake_hv import FakeHv
from rclpy.parameter import Parameter
from ros_testing import Inbox, Spinner, wait_for
from waiting import GENEROUS_S
from sequence_files import scaled
from softblock_interfaces.action import RunSequence
from softblock_interfaces.msg import SequenceEvent

from softblock_ros import run_sequence
from softblock_ros.client import ActionClient
from softblock_ros.sequencer_node import SequencerNode
from softblock_ros.sim_arm_node import SimArmNode

pytestmark = pytest.mark.integration

CHANNELS = ["front", "back", "trunk", "leg_front_left", "leg_front_right", "leg_rear_left", "leg_rear_right"]
RUN_TIMEOUT = 40.0


# The fake driver ramps and publishes from this test process, which a loaded host (or the other pytest worker) can
# stall for seconds: the sequencer's windows that a test does not test are longer than any such stall. A
# precondition waits for its state, a safe stop for its ramps, and a driver counts as lost only after 10 s (the
# longest the parameter allows) of silence. Their timing is tested on the engine's injected clock
# (tests/sequencing); the silent driver's test has its own sequencer with the default state timeout.
LONG_WINDOWS = {"settle_time_s": 30.0, "safe_stop_timeout_s": 60.0, "state_timeout_s": 10.0}


def make_sequencer(directory, windows=LONG_WINDOWS, **kwargs) -> SequencerNode:
    return SequencerNode(parameter_overrides=[Parameter("sequences_dir", value=str(directory)),
                                              *(Parameter(name, value=value) for name, value in windows.items())],
                         **kwargs)


def make_arm(**kwargs) -> SimArmNode:
    return SimArmNode(parameter_overrides=[
        Parameter("max_speed_m_per_s", value=2.0), Parameter("max_acceleration_m_per_s2", value=20.0),
        Parameter("publish_rate_hz", value=100.0)], **kwargs)


@pytest.fixture(scope="module")
def stack(ros_context, spin, tmp_path_factory):
    directory = tmp_path_factory.mktemp("sequences")
    sequencer = make_sequencer(directory, context=ros_context)
    arm = make_arm(context=ros_context)
    hv = FakeHv(CHANNELS, context=ros_context)
    client = rclpy.create_node("sequencer_test_client", context=ros_context)
    events = Inbox(client, SequenceEvent, "sequencer/events", 100)
    poses = Inbox(client, PoseStamped, "arm/pose", 100)
    action = ActionClient(client, RunSequence, "sequencer/run")
    spin(sequencer, arm, hv, client)
    assert action.wait_for_server(timeout_sec=GENEROUS_S)
    return {"dir": directory, "hv": hv, "events": events, "action": action, "poses": poses, "client": client}


@pytest.fixture
def hv(stack):
    stack["hv"].reset()
    stack["events"].messages.clear()
    return stack["hv"]


class Run:
    """One RunSequence goal: its handle, the feedback it got, and a way to wait for the result."""

    def __init__(self, action: ActionClient, sequence: str):
        self.feedback = []
        future = action.send_goal_async(RunSequence.Goal(sequence=sequence),
                                        feedback_callback=lambda msg: self.feedback.append(msg.feedback))
        self.handle = wait_for(future.done, what="the goal response") and future.result()

    def result(self):
        future = self.handle.get_result_async()
        wait_for(future.done, RUN_TIMEOUT, what="the sequence result")
        return future.result().status, future.result().result


def channels_off(hv: FakeHv) -> bool:
    return all(channel.measured_voltage == 0.0 for channel in hv.channels.values())


def test_finger_grasp_runs_to_success(stack, hv):
    run = Run(stack["action"], scaled("finger_grasp", stack["dir"], speed=2.0))
    assert run.handle.accepted
    status, result = run.result()
    assert status == GoalStatus.STATUS_SUCCEEDED and result.success, result.message
    assert result.failed_step == ""
    assert len(result.step_names) == len(result.step_durations) == 12
    assert [ramp for ramp in hv.ramps] == [("back", 2400.0), ("back", 0.0), ("front", 2400.0), ("front", 0.0),
                                           ("back", 2400.0), ("back", 0.0)]
    assert channels_off(hv) and hv.heartbeats > 0  # heartbeats signed for the session
    assert hv.control.owner is None and hv.control.ended == "control released by 'sequencer'"
    assert [(f.step_index, f.phase) for f in run.feedback if f.phase == "succeeded"] == [(i, "succeeded")
                                                                                       for i in range(12)]
    assert all(f.step_count == 12 for f in run.feedback)
    events = stack["events"].wait(lambda msg: msg.step_name == "close_back_rest" and msg.phase == "succeeded")
    assert events.sequence == "finger_grasp"
    phases = [(msg.step_index, msg.phase) for msg in stack["events"].messages]
    assert phases == [(i, phase) for i in range(12) for phase in ("started", "succeeded")]
    stack["poses"].messages.clear()
    at = stack["poses"].wait().pose.position
    assert (at.x, at.y, at.z) == pytest.approx((0.45, 0.3, 0.25))  # withdrawn above B


def own_stack(ros_context, spin, directory, namespace: str, windows=LONG_WINDOWS, arm=True) -> dict:
    """A fake driver, a sequencer with ``windows`` (and the arm) of their own in ``namespace``, and a client."""
    hv = FakeHv(CHANNELS, context=ros_context, namespace=namespace)
    client = rclpy.create_node("own_stack_client", context=ros_context, namespace=namespace)
    events = Inbox(client, SequenceEvent, "sequencer/events", 100)
    action = ActionClient(client, RunSequence, "sequencer/run")
    nodes = [make_sequencer(directory, windows, context=ros_context, namespace=namespace), hv, client]
    spin(*nodes, *([make_arm(context=ros_context, namespace=namespace)] if arm else []))
    assert action.wait_for_server(timeout_sec=GENEROUS_S)
    return {"hv": hv, "events": events, "action": action}


def test_a_goal_sent_before_the_arm_is_up_runs_once_the_arm_appears(ros_context, spin, tmp_path):
    """Start-up order does not matter: the sequencer waits the default server_timeout_s for a server it has not
    discovered yet (a stack started at once on a loaded host can take seconds), here an arm started once the
    sequence's first step, a move, has begun."""
    namespace = "/late_arm"
    late = own_stack(ros_context, spin, tmp_path, namespace, arm=False)
    run = Run(late["action"], scaled("finger_grasp", tmp_path, speed=2.0))
    late["events"].wait(lambda msg: (msg.step_index, msg.phase) == (0, "started"))
    spin(make_arm(context=ros_context, namespace=namespace))
    status, result = run.result()
    assert status == GoalStatus.STATUS_SUCCEEDED and result.success, result.message


def test_hv_fault_mid_sequence_stops_in_the_safe_state(stack, hv):
    hv.fault_during_ramp = ("back", 2400.0, "front")  # front trips while the back fingers open
    status, result = Run(stack["action"], scaled("finger_grasp", stack["dir"], speed=2.0,
                                                 slew_rate=20_000.0)).result()
    assert status == GoalStatus.STATUS_ABORTED and not result.success
    assert result.failed_step == "open_back"
    assert "HV fault (front: OVER_CURRENT)" in result.message
    assert "safe state" in result.message
    assert channels_off(hv)
    assert hv.ramps[-1] == ("back", 0.0)  # the live channel was ramped down
    failed = stack["events"].wait(lambda msg: msg.phase == "failed")
    assert failed.step_name == "open_back"


def test_a_silent_driver_fails_the_step_naming_the_lost_driver(ros_context, spin, tmp_path):
    """A short state timeout. Which step the lapse falls in depends on the host's speed, so the test asserts only
    what holds in any step after the silence began: once the driver is lost, every channel counts as live and
    ramps to 0 V, in an order the driver's executor decides."""
    own = own_stack(ros_context, spin, tmp_path, "/silent_driver", windows={**LONG_WINDOWS, "state_timeout_s": 2.0})
    hv = own["hv"]
    run = Run(own["action"], scaled("finger_grasp", tmp_path, speed=2.0))
    own["events"].wait(lambda msg: msg.step_name == "surround_object" and msg.phase == "started")
    hv.silent = True  # hv/state stops, as when the network to the driver fails
    status, result = run.result()
    assert status == GoalStatus.STATUS_ABORTED and not result.success
    assert result.failed_step not in ("", "above_object", "open_back")  # a step after the driver fell silent
    assert "HV driver lost: no hv/state for" in result.message, result.message
    assert "safe state: arm stopped, ['front', 'back'] channel(s) ramped to 0 V" in result.message
    assert sorted(hv.ramps[-2:]) == [("back", 0.0), ("front", 0.0)] and channels_off(hv)  # its ramps still answered


def test_cancel_mid_sequence_ramps_down_and_reports_canceled(stack, hv):
    run = Run(stack["action"], scaled("finger_grasp", stack["dir"], speed=0.05))
    stack["events"].wait(lambda msg: msg.step_name == "surround_object" and msg.phase == "started")
    assert hv.channels["back"].measured_voltage == 2400.0
    cancel = run.handle.cancel_goal_async()
    wait_for(cancel.done, what="the cancel response")
    status, result = run.result()
    assert status == GoalStatus.STATUS_CANCELED and not result.success
    assert result.message.startswith("canceled during step 'surround_object'")
    assert channels_off(hv) and hv.ramps[-1] == ("back", 0.0)
    stack["poses"].messages.clear()
    wait_for(lambda: len(stack["poses"].messages) >= 2, what="two arm poses")
    assert stack["poses"].messages[0].pose == stack["poses"].messages[1].pose  # the arm holds
    stack["events"].wait(lambda msg: msg.phase == "canceled")


@pytest.mark.parametrize("sequence, message", [
    ("no_such_sequence", "rejected: sequence='no_such_sequence': no such file"),
    ("BROKEN", "invalid YAML"),
    ("TOO_HIGH", "step 'open' (steps[0]): ramp.target=9000: above the voltage ceiling 2500 V"),
])
def test_bad_sequences_are_refused_with_a_clear_message(stack, hv, sequence, message):
    broken, too_high = stack["dir"] / "broken.yaml", stack["dir"] / "too_high.yaml"
    broken.write_text("name: broken\nsteps: [\n")
    too_high.write_text(yaml.safe_dump({"name": "too_high", "channels": ["back"], "steps": [
        {"name": "open", "ramp": {"channel": "back", "target": 9000}}]}))
    sequence = {"BROKEN": "broken", "TOO_HIGH": "too_high"}.get(sequence, sequence)
    status, result = Run(stack["action"], sequence).result()
    assert status == GoalStatus.STATUS_ABORTED and not result.success
    assert message in result.message
    assert hv.ramps == []


@pytest.mark.parametrize("goal", ["/etc/passwd", "../sequences/finger_grasp", "passwd"])
def test_goals_name_sequences_and_never_read_other_files(stack, hv, goal):
    link = stack["dir"] / "passwd.yaml"
    if not link.is_symlink():
        link.symlink_to("/etc/passwd")
    status, result = Run(stack["action"], goal).result()
    assert status == GoalStatus.STATUS_ABORTED and not result.success
    assert "no paths" in result.message or "links outside" in result.message
    assert "root:" not in result.message and "/bin/" not in result.message


def test_a_sequence_is_refused_while_another_client_holds_hv_control(stack, hv):
    hv.control.claim("another client", time.monotonic())
    status, result = Run(stack["action"], scaled("finger_grasp", stack["dir"], speed=2.0)).result()
    assert status == GoalStatus.STATUS_ABORTED and not result.success
    assert result.message.startswith("hv/claim_control refused: control is held by 'another client'")
    assert hv.ramps == [] and hv.control.owner == "another client"


def test_second_goal_is_rejected_while_one_runs(stack, hv):
    first = Run(stack["action"], scaled("finger_grasp", stack["dir"], speed=0.5))
    stack["events"].wait(lambda msg: msg.phase == "started")
    second = Run(stack["action"], "trunk_flower")
    assert not second.handle.accepted
    first.handle.cancel_goal_async()
    status, _ = first.result()
    assert status == GoalStatus.STATUS_CANCELED


def servers(node, name: str = "/sequencer/run") -> int:
    return node.count_publishers(f"{name}/_action/status")


def test_a_second_sequencer_stands_by_while_one_serves_so_a_goal_has_one_answer(stack, hv):
    """Two sequencers used to accept one finger_grasp goal: one ran it to 2.4 kV, the caller got ABORTED from
    the other. A sequencer that finds another serving stands by instead of serving: the goal has one answer, the
    first sequencer's, and runs once."""
    spinner = Spinner(stack["client"].context, num_threads=4)
    try:
        second = make_sequencer(stack["dir"], context=stack["client"].context)
        spinner.add(second)
        run = Run(stack["action"], scaled("finger_grasp", stack["dir"], speed=2.0))  # while the second one looks
        wait_for(second.standing_by.is_set, what="the second sequencer standing by")
        assert servers(stack["client"]) == 1 and not second.serving.is_set()
        status, result = run.result()
        assert status == GoalStatus.STATUS_SUCCEEDED, result.message
        started = [msg for msg in stack["events"].messages if msg.phase == "started" and msg.step_index == 0]
        assert len(started) == 1 and not second.serving.is_set()  # one sequencer ran it
    finally:
        spinner.close()
    assert hv.control.owner is None


def test_of_two_sequencers_started_together_neither_serves_until_one_is_stopped(ros_context, tmp_path):
    """Started at once, neither has a server for the other to see; each sees a node of its own name and stands
    by. Once one is stopped the other serves, and a goal is answered by it alone."""
    first, second = (make_sequencer(tmp_path, context=ros_context, namespace="/twins") for _ in range(2))
    client = rclpy.create_node("twins_client", context=ros_context)
    action = ActionClient(client, RunSequence, "/twins/sequencer/run")
    spinner, stopped = Spinner(ros_context, num_threads=4), Spinner(ros_context, num_threads=2)
    spinner.add(first, client)
    stopped.add(second)
    try:
        wait_for(lambda: first.standing_by.is_set() and second.standing_by.is_set(), what="both standing by")
        assert servers(client, "/twins/sequencer/run") == 0
        stopped.close()  # the second sequencer ends
        wait_for(first.serving.is_set, what="the remaining sequencer serving")
        assert action.wait_for_server(timeout_sec=GENEROUS_S)
        status, result = Run(action, "missing").result()  # accepted by the one server, refused in its result
        assert status == GoalStatus.STATUS_ABORTED and result.message.startswith("rejected: "), result.message
    finally:
        stopped.close()
        spinner.close()


def test_legged_gait_pulses_the_legs(stack, hv):
    status, result = Run(stack["action"], scaled("legged_gait", stack["dir"], speed=0.0, slew_rate=16_000.0,
                                                 cycles=2)).result()
    assert status == GoalStatus.STATUS_SUCCEEDED, result.message
    assert result.step_names == ["walk_forward", "turn_left", "turn_right"]
    assert hv.ramps == []  # one periodic command per train, never one action per edge
    assert sorted(hv.pulses) == sorted([(("leg_front_left", "leg_rear_right"), 2),
                                        (("leg_front_right", "leg_rear_left"), 2),
                                        (("leg_front_right", "leg_rear_right"), 2),
                                        (("leg_front_left", "leg_rear_left"), 2)])
    assert channels_off(hv)


def test_command_line_client_prints_steps_and_result(stack, hv, capsys):
    name = scaled("trunk_flower", stack["dir"], speed=2.0)
    assert run_sequence.main(["run_sequence", name, "--timeout", str(RUN_TIMEOUT)]) == 0
    output = capsys.readouterr().out
    assert "[2/8] open_trunk: running  (ii) actuate the trunk to open)" in output
    assert "sequence 'trunk_flower': all 8 steps succeeded" in output
    assert run_sequence.main(["run_sequence", "no_such_sequence", "--timeout", str(RUN_TIMEOUT)]) == 1
    assert "rejected: sequence='no_such_sequence'" in capsys.readouterr().out


def test_command_line_client_timeout_cancels_into_the_safe_state(stack, hv, capsys):
    name = scaled("finger_grasp", stack["dir"], speed=0.05)
    assert run_sequence.main(["run_sequence", name, "--timeout", "1.5"]) == 2
    output = capsys.readouterr().out
    assert "timed out, canceling ..." in output and "canceled during step" in output
    assert channels_off(hv)

"""Sequence engine against a fake robot: order, preconditions, timeouts, faults, cancel, safe reactions. The engine
runs on a clock that ticks with its polls (no thread races it): every outcome follows from the order of events."""
import threading
from pathlib import Path

import pytest
from fake_robot import FakeMotion, FakeRobot, TickingClock
from hypothesis import given, settings
from hypothesis import strategies as st

from sequencing.engine import SequenceEngine
from sequencing.ports import ChannelReading, Outcome, RobotError, RunOptions
from sequencing.schema import load_sequence, parse_sequence

pytestmark = pytest.mark.fast

SEQUENCES = Path(__file__).resolve().parents[2] / "config" / "sequences"
FAST = RunOptions(poll_period_s=0.002, settle_time_s=0.02, safe_stop_timeout_s=0.5)
FINGER_GRASP = load_sequence("finger_grasp", SEQUENCES)
LINK = 4  # a fault bit; the engine knows none by name


def run(sequence, robot, cancel=None, options=FAST):
    events = []
    result = SequenceEngine(robot, options, events.append, clock=TickingClock(1e-3)).run(sequence, cancel)
    return result, events


def channels_safe(robot) -> bool:
    return all(reading.voltage == 0.0 and not reading.output_enabled for reading in robot.states.values())


def test_finger_grasp_runs_every_step_in_order():
    robot = FakeRobot(FINGER_GRASP.channels)
    result, events = run(FINGER_GRASP, robot)
    assert result.success, result.message
    assert result.step_names == [step.name for step in FINGER_GRASP.steps]
    assert len(result.step_durations) == 12 and min(result.step_durations) >= 0
    assert [(call[1], call[2]) for call in robot.ramps()] == [
        ("back", 2400.0), ("back", 0.0), ("front", 2400.0), ("front", 0.0), ("back", 2400.0), ("back", 0.0)]
    assert [phase for event in events[:3] for phase in [event.phase]] == ["precondition", "running", "succeeded"]
    assert [event.index for event in events if event.phase == "succeeded"] == list(range(12))
    assert all(event.count == 12 for event in events)
    assert channels_safe(robot)
    assert ("stop_arm",) not in robot.calls


def test_precondition_mismatch_fails_before_the_step_and_ramps_down():
    robot = FakeRobot(FINGER_GRASP.channels)
    robot.states["front"] = ChannelReading(1500.0, 0, "", True)  # left energised
    result, events = run(FINGER_GRASP, robot)
    assert not result.success and not result.canceled
    assert result.failed_step == "above_object"
    assert "precondition: channel 'front' at 1500 V, expected 0 +- 50 V" in result.message
    assert not [call for call in robot.calls if call[0] == "move_arm"]
    assert ("stop_arm",) in robot.calls and channels_safe(robot)
    assert events[-1].phase == "failed"


def test_missing_channel_and_latched_fault_block_the_start():
    robot = FakeRobot(["front"])
    result, _ = run(FINGER_GRASP, robot)
    assert "channel 'back' not reported by the HV driver" in result.message
    robot = FakeRobot(FINGER_GRASP.channels)
    robot.inject_fault("back")
    result, _ = run(FINGER_GRASP, robot)
    assert "precondition: HV fault latched (back: OVER_CURRENT); reset faults first" in result.message


def test_fault_during_a_ramp_cancels_it_and_reaches_the_safe_state():
    def fault_on_front_ramp(robot, call):
        if call[:3] == ("ramp", "front", 2400.0):
            robot.inject_fault("front")
            return robot.hang()

    robot = FakeRobot(FINGER_GRASP.channels, fault_on_front_ramp)
    result, events = run(FINGER_GRASP, robot)
    assert result.failed_step == "grip_front"
    assert "HV fault (front: OVER_CURRENT)" in result.message
    assert robot.hanging[0].canceled
    assert channels_safe(robot)
    assert ("estop",) not in robot.calls  # the faulted channel is already off, the other ramped down
    assert robot.ramps()[-1][1:3] == ("back", 0.0) or robot.states["back"].voltage == 0.0
    assert "safe state" in events[-1].message


def test_a_safe_stop_ramps_down_every_channel_whose_state_is_unknown():
    # The driver's state stops arriving while its last word (front off) is out of date: front was just raised.
    def driver_lost_after_front_ramp(robot, call):
        if call[:3] == ("ramp", "front", 2400.0):
            robot.states = {channel: ChannelReading(0.0, LINK, "HV driver lost: no hv/state for 0.5 s", False,
                                                    stale=True) for channel in robot.states}
            return FakeMotion(Outcome(True, "", 2400.0))

    robot = FakeRobot(FINGER_GRASP.channels, driver_lost_after_front_ramp)
    result, _ = run(FINGER_GRASP, robot)
    assert not result.success and "HV driver lost" in result.message, result.message
    assert result.failed_step == "grip_front"
    assert robot.ramps("front")[-1][2] == 0.0, robot.calls  # the safe stop ramped the unknown front down


def test_timeout_cancels_the_motion():
    robot = FakeRobot(FINGER_GRASP.channels, lambda robot, call: robot.hang() if call[0] == "move_arm" else None)
    sequence = parse_sequence({"name": "t", "channels": ["front"], "steps": [
        {"name": "go", "timeout": 0.05, "move_arm": {"position": [0, 0, 0.1], "orientation": [0, 0, 0, 1]}}]})
    result, _ = run(sequence, robot)
    assert "step 'go' failed: timed out after 0.05 s" in result.message
    assert robot.hanging[0].canceled and ("stop_arm",) in robot.calls


def test_cancel_mid_step_gives_a_canceled_result_in_the_safe_state():
    cancel = threading.Event()

    def cancel_while_surrounding(robot, call):
        if call[0] == "move_arm" and call[1][2] == 0.12:
            cancel.set()
            return robot.hang()

    robot = FakeRobot(FINGER_GRASP.channels, cancel_while_surrounding)
    result, events = run(FINGER_GRASP, robot, cancel)
    assert result.canceled and not result.success
    assert result.failed_step == "surround_object"
    assert result.message.startswith("canceled during step 'surround_object'")
    assert robot.hanging[0].canceled
    assert robot.ramps()[-1][1:3] == ("back", 0.0) and channels_safe(robot)
    assert events[-1].phase == "canceled"


def test_failed_ramp_down_falls_back_to_estop():
    def refuse_from_release_on(robot, call):
        if call[:3] == ("ramp", "front", 0.0):
            robot.refuse_ramps = True

    robot = FakeRobot(FINGER_GRASP.channels, refuse_from_release_on)
    result, _ = run(FINGER_GRASP, robot)
    assert result.failed_step == "release_front"
    assert "ramp of 'front' to 0 V failed: refused: faults latched" in result.message
    assert "ramp-down failed (front: refused: faults latched)" in result.message
    assert robot.calls[-1] == ("estop",) and "e-stop sent" in result.message


def test_on_failure_estop_skips_the_ramp_down():
    sequence = parse_sequence({"name": "t", "channels": ["front"], "steps": [
        {"name": "up", "ramp": {"channel": "front", "target": 1000.0}},
        {"name": "check", "on_failure": "estop", "precondition": {"voltages": {"front": 0.0}},
         "wait": {"duration": 0.0}}]})
    robot = FakeRobot(["front"])
    result, _ = run(sequence, robot)
    assert result.failed_step == "check" and "on_failure: estop; e-stop sent" in result.message
    assert len(robot.ramps()) == 1 and robot.calls[-2:] == [("stop_arm",), ("estop",)]


def test_unreachable_backend_fails_the_step_with_its_message():
    robot = FakeRobot(FINGER_GRASP.channels)
    robot.unreachable = True
    result, _ = run(FINGER_GRASP, robot)
    assert result.failed_step == "above_object" and "arm/move: action server not available" in result.message


def test_ramp_duration_sets_the_slew_rate_of_the_minimum_jerk_ramp():
    sequence = parse_sequence({"name": "t", "channels": ["front"], "steps": [
        {"name": "up", "ramp": {"channel": "front", "target": 2000.0, "duration": 2.0}}]})
    robot = FakeRobot(["front"])
    assert run(sequence, robot)[0].success
    assert robot.ramps() == [("ramp", "front", 2000.0, pytest.approx(1.875 * 2000.0 / 2.0))]


def test_ramp_settling_off_target_fails():
    def stuck_at_1200(robot, call):
        if call[:3] == ("ramp", "front", 2000.0):
            robot.states["front"] = ChannelReading(1200.0, 0, "", True)
            return FakeMotion(Outcome(True, "", 1200.0))

    robot = FakeRobot(["front"], stuck_at_1200)
    sequence = parse_sequence({"name": "t", "channels": ["front"], "steps": [
        {"name": "up", "ramp": {"channel": "front", "target": 2000.0}}]})
    result, _ = run(sequence, robot)
    assert "channel 'front' ended at 1200 V, expected 2000 +- 50 V" in result.message


def test_parallel_failure_cancels_the_sibling_and_names_the_branch():
    def branch_behaviour(robot, call):
        if call[0] == "move_arm":
            return robot.hang()
        if call[:3] == ("ramp", "front", 2000.0):
            raise RobotError("hv/ramp: goal rejected")

    sequence = parse_sequence({"name": "t", "channels": ["front"], "steps": [{"name": "both", "parallel": [
        {"name": "go", "move_arm": {"position": [0, 0, 0.1], "orientation": [0, 0, 0, 1]}},
        {"name": "grip", "ramp": {"channel": "front", "target": 2000.0}}]}]})
    robot = FakeRobot(["front"], branch_behaviour)
    result, _ = run(sequence, robot)
    assert result.failed_step == "both"
    assert "step 'both' failed: grip: hv/ramp: goal rejected" in result.message
    assert robot.hanging[0].canceled


def test_a_gait_is_one_periodic_command_per_train_never_one_per_edge():
    gait = load_sequence("legged_gait", SEQUENCES)
    robot = FakeRobot(gait.channels)
    result, events = run(gait, robot)
    assert result.success, result.message
    assert robot.ramps() == []
    assert robot.pulses()[:2] == [
        ("pulse", ("leg_front_left", "leg_rear_right"), 600.0, 5.0, 0.5, 0.0, 20, "smooth", 16000.0),
        ("pulse", ("leg_front_right", "leg_rear_left"), 600.0, 5.0, 0.5, 0.5, 20, "smooth", 16000.0)] or \
        robot.pulses()[:2][::-1] == [  # the two branches of the parallel step start in either order
        ("pulse", ("leg_front_left", "leg_rear_right"), 600.0, 5.0, 0.5, 0.0, 20, "smooth", 16000.0),
        ("pulse", ("leg_front_right", "leg_rear_left"), 600.0, 5.0, 0.5, 0.5, 20, "smooth", 16000.0)]
    assert len(robot.pulses()) == 4
    assert channels_safe(robot)


@settings(max_examples=25, deadline=None)
@given(fault_at=st.integers(0, 5), channel=st.sampled_from(["front", "back"]), hang=st.booleans())
def test_property_any_fault_during_any_ramp_ends_failed_and_safe(fault_at, channel, hang):
    """Whichever ramp a fault hits, the run fails at that step and every channel ends at 0 V, off."""
    count = {"ramps": 0}

    def fault_on_nth_ramp(robot, call):
        if call[0] != "ramp":
            return None
        count["ramps"] += 1
        if count["ramps"] == fault_at + 1:
            robot.inject_fault(channel)
            # The fault hits while the ramp runs, or right after it finished.
            return robot.hang() if hang else FakeMotion(Outcome(True, "", call[2]))

    robot = FakeRobot(FINGER_GRASP.channels, fault_on_nth_ramp)
    result, _ = run(FINGER_GRASP, robot)
    ramp_steps = [step.name for step in FINGER_GRASP.steps if hasattr(step, "channel")]
    assert not result.success
    assert result.failed_step == ramp_steps[fault_at]
    assert "HV fault" in result.message
    assert channels_safe(robot) or ("estop",) in robot.calls


def test_ramp_waits_for_the_measured_voltage_to_settle():
    """The driver reports the ramp done when the setpoint arrives; the measured voltage lags a little."""
    def lagging(robot, call):
        if call[:3] == ("ramp", "front", 2000.0):
            robot.states["front"] = ChannelReading(1700.0, 0, "", True)
            robot.after_readings(3, lambda r: r.states.update(front=ChannelReading(1990.0, 0, "", True)))
            return FakeMotion(Outcome(True, "", 1700.0))

    sequence = parse_sequence({"name": "t", "channels": ["front"], "steps": [
        {"name": "up", "ramp": {"channel": "front", "target": 2000.0}}]})
    result, _ = run(sequence, FakeRobot(["front"], lagging), options=RunOptions(poll_period_s=0.002, settle_time_s=5.0))
    assert result.success, result.message


def one_train(cycles=1, **fields):
    spec = {"channels": ["front"], "voltage": 600.0, "frequency": 5.0, "duty": 0.5, "cycles": cycles,
            "slew_rate": 20000.0, **fields}
    return parse_sequence({"name": "t", "channels": ["front"], "steps": [{"name": "trot", "pulse_train": spec}]})


def test_square_edges_are_asked_of_the_driver_without_a_slew_rate():
    robot = FakeRobot(["front"])
    spec = {"channels": ["front"], "voltage": 600.0, "frequency": 5.0, "duty": 0.5, "cycles": 100, "edge": "square"}
    sequence = parse_sequence({"name": "t", "channels": ["front"], "steps": [{"name": "trot", "pulse_train": spec}]})
    result, events = run(sequence, robot)
    assert result.success, result.message
    assert robot.pulses() == [("pulse", ("front",), 600.0, 5.0, 0.5, 0.0, 100, "square", 0.0)]
    assert "100 cycles on ['front'] at 5 Hz (completed 100 cycles)" in events[-1].message


def test_a_refused_train_fails_the_step_naming_the_reason():
    def refuse(robot, call):
        if call[0] == "pulse":
            return FakeMotion(Outcome(False, "channel 'front': 5 Hz at 2400 V ... needs edges of at most 100 ms"))

    robot = FakeRobot(["front"], refuse)
    result, _ = run(one_train(), robot)
    assert not result.success and result.failed_step == "trot"
    assert "pulse train on ['front'] failed: channel 'front': 5 Hz at 2400 V" in result.message
    assert channels_safe(robot)


def test_a_fault_during_a_train_cancels_it_and_ends_safe():
    def fault_while_pulsing(robot, call):
        if call[0] == "pulse":
            robot.states["front"] = ChannelReading(600.0, 0, "", True)
            robot.after_readings(5, lambda r: r.inject_fault("front"))
            return robot.hang()

    robot = FakeRobot(["front"], fault_while_pulsing)
    result, _ = run(one_train(cycles=100), robot, options=RunOptions(poll_period_s=0.002))
    assert not result.success and "HV fault" in result.message
    assert robot.hanging[0].canceled and channels_safe(robot)


def test_a_train_that_ends_with_a_channel_still_up_fails():
    def stuck(robot, call):
        if call[0] == "pulse":
            robot.states["front"] = ChannelReading(600.0, 0, "", True)
            return FakeMotion(Outcome(True, "completed 1 cycles"))

    result, _ = run(one_train(), FakeRobot(["front"], stuck), options=RunOptions(poll_period_s=0.002,
                                                                                 settle_time_s=0.05))
    assert not result.success and "channel 'front' ended at 600 V, expected 0 +- 50 V" in result.message


def test_unexpected_backend_error_still_ends_in_the_safe_state():
    def broken_arm(robot, call):
        if call[0] == "move_arm" and call[1][2] == 0.12:
            raise KeyError("controller vanished")

    robot = FakeRobot(FINGER_GRASP.channels, broken_arm)
    with pytest.raises(KeyError, match="controller vanished"):
        run(FINGER_GRASP, robot)
    assert ("stop_arm",) in robot.calls and channels_safe(robot)
    assert robot.ramps()[-1][1:3] == ("back", 0.0)

"""Simulated arm: reaches targets, respects speed/acceleration limits, slerps orientation, brakes on stop."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sim_fallback.arm import ArmLimits, Pose, SimulatedArm

pytestmark = pytest.mark.fast

DT = 0.01
LIMITS = ArmLimits(max_speed_m_per_s=0.2, max_acceleration_m_per_s2=0.5, max_angular_speed_rad_per_s=1.0, max_angular_acceleration_rad_per_s2=2.0)


def run(arm: SimulatedArm, max_steps: int = 10_000) -> list[Pose]:
    poses = [arm.pose]
    for _ in range(max_steps):
        if not arm.moving:
            return poses
        poses.append(arm.step(DT))
    raise AssertionError("the arm never settled")


def speeds(poses: list[Pose]) -> np.ndarray:
    positions = np.array([pose.position for pose in poses])
    return np.linalg.norm(np.diff(positions, axis=0), axis=1) / DT


def test_reaches_target_position_and_orientation():
    target = Pose((0.3, -0.1, 0.2), tuple(Rotation.from_euler("z", 90, degrees=True).as_quat()))
    arm = SimulatedArm(Pose(), LIMITS)
    arm.move_to(target)
    run(arm)
    assert arm.reached(target)
    assert not arm.moving and arm.target is None


def test_speed_and_acceleration_stay_within_limits():
    arm = SimulatedArm(Pose(), LIMITS)
    arm.move_to(Pose((0.5, 0.0, 0.0)))
    velocity = speeds(run(arm))
    assert velocity.max() <= LIMITS.max_speed_m_per_s * 1.001
    assert velocity.max() >= LIMITS.max_speed_m_per_s * 0.99  # long move: it does cruise at the limit
    assert np.abs(np.diff(velocity)).max() / DT <= LIMITS.max_acceleration_m_per_s2 * 1.01


def test_move_speed_below_limit_is_honoured_and_above_limit_clamped():
    slow = SimulatedArm(Pose(), LIMITS)
    slow.move_to(Pose((0.5, 0.0, 0.0)), max_speed_m_per_s=0.05)
    assert speeds(run(slow)).max() <= 0.05 * 1.001
    fast = SimulatedArm(Pose(), LIMITS)
    fast.move_to(Pose((0.5, 0.0, 0.0)), max_speed_m_per_s=5.0)
    assert speeds(run(fast)).max() <= LIMITS.max_speed_m_per_s * 1.001


def test_orientation_is_slerped_along_the_path():
    target = Pose((0.2, 0.0, 0.0), tuple(Rotation.from_euler("z", 60, degrees=True).as_quat()))
    arm = SimulatedArm(Pose(), LIMITS)
    arm.move_to(target)
    for pose in run(arm):
        fraction = pose.position[0] / 0.2
        yaw = Rotation.from_quat(pose.orientation).as_euler("xyz", degrees=True)[2]
        assert yaw == pytest.approx(60 * fraction, abs=1e-6)


def test_pure_rotation_respects_the_angular_speed_limit():
    target = Pose((0.0, 0.0, 0.0), tuple(Rotation.from_euler("x", 180, degrees=True).as_quat()))
    arm = SimulatedArm(Pose(), LIMITS)
    arm.move_to(target)
    poses = run(arm)
    angles = [Pose().angle_to(pose) for pose in poses]
    assert np.diff(angles).max() / DT <= LIMITS.max_angular_speed_rad_per_s * 1.001
    assert arm.reached(target)


def test_stop_brakes_smoothly_on_the_path_and_holds():
    arm = SimulatedArm(Pose(), LIMITS)
    arm.move_to(Pose((1.0, 0.0, 0.0)))
    for _ in range(200):
        arm.step(DT)
    speed = arm.speed()
    assert speed > 0.1
    x_at_stop = arm.pose.position[0]
    arm.stop()
    poses = run(arm)
    expected_braking = speed ** 2 / (2 * LIMITS.max_acceleration_m_per_s2)
    assert arm.pose.position[0] - x_at_stop == pytest.approx(expected_braking, rel=0.05)
    assert np.abs(np.diff(speeds(poses))).max() / DT <= LIMITS.max_acceleration_m_per_s2 * 1.01
    assert arm.pose.position[1:] == (0.0, 0.0)
    assert arm.step(1.0) == arm.pose  # holds


def test_new_target_while_moving_keeps_the_present_speed():
    arm = SimulatedArm(Pose(), LIMITS)
    arm.move_to(Pose((1.0, 0.0, 0.0)))
    for _ in range(100):
        arm.step(DT)
    speed = arm.speed()
    arm.move_to(Pose((0.5, 0.5, 0.0)))
    assert arm.speed() == pytest.approx(speed, rel=1e-6)
    run(arm)
    assert arm.reached(Pose((0.5, 0.5, 0.0)))


def test_target_within_tolerance_counts_as_reached_at_once():
    arm = SimulatedArm(Pose(), LIMITS)
    arm.move_to(Pose((LIMITS.position_tolerance_m / 2, 0.0, 0.0)))
    assert not arm.moving


@pytest.mark.parametrize("kwargs, parameter", [
    ({"position": (0.0, 0.0)}, "position"),
    ({"position": (0.0, math.nan, 0.0)}, "position"),
    ({"orientation": (0.0, 0.0, 0.0, 2.0)}, "orientation"),
])
def test_invalid_pose_names_the_field(kwargs, parameter):
    with pytest.raises(ValueError, match=parameter):
        Pose(**kwargs)


def test_invalid_limits_and_arguments_name_the_parameter():
    with pytest.raises(ValueError, match="max_speed_m_per_s"):
        ArmLimits(max_speed_m_per_s=0.0)
    arm = SimulatedArm()
    with pytest.raises(ValueError, match="max_speed_m_per_s"):
        arm.move_to(Pose((0.1, 0.0, 0.0)), max_speed_m_per_s=-1.0)
    with pytest.raises(ValueError, match="dt"):
        arm.step(-0.1)


@pytest.mark.parametrize("position, max_speed", [((0.0, 0.0, 1e30), 1e-300), ((1e308, 1e308, 0.0), 0.0)])
def test_a_move_too_long_to_time_is_refused(position, max_speed):
    """Distance / speed underflows to a rate of 0 (found by fuzzing arm/move): refused, not a ZeroDivisionError."""
    arm = SimulatedArm()
    with pytest.raises(ValueError, match=r"target=.*: a move of finite duration .* cannot be timed"):
        arm.move_to(Pose(position), max_speed_m_per_s=max_speed)
    assert not arm.moving


@settings(max_examples=30, deadline=None)
@given(
    target=st.tuples(*[st.floats(-0.5, 0.5)] * 3),
    euler=st.tuples(*[st.floats(-180, 180)] * 3),
    max_speed_m_per_s=st.one_of(st.just(0.0), st.floats(0.02, 0.5)),
)
def test_property_every_move_settles_on_target_within_limits(target, euler, max_speed_m_per_s):
    goal = Pose(target, tuple(Rotation.from_euler("xyz", euler, degrees=True).as_quat()))
    arm = SimulatedArm(Pose((0.1, 0.1, 0.1)), LIMITS)
    arm.move_to(goal, max_speed_m_per_s=max_speed_m_per_s)
    poses = run(arm)
    assert arm.reached(goal)
    limit = LIMITS.max_speed_m_per_s if max_speed_m_per_s == 0 else min(max_speed_m_per_s, LIMITS.max_speed_m_per_s)
    if len(poses) > 1:
        assert speeds(poses).max() <= limit * 1.001

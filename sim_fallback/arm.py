"""Simulated manipulator: a kinematic tool pose that moves to a target with finite speed and acceleration.

The tool frame travels on the straight line from where a move starts to its target while its
orientation is slerped along; one path parameter ``s`` in [0, 1] drives both, so position and
orientation arrive together. ``s`` follows a trapezoidal speed profile: it accelerates at the
allowed rate, cruises at the speed limit and brakes so that it stops exactly at the target. The
limits on ``ds/dt`` come from the linear and the angular limits, whichever binds.

Time is passed in by the caller (``step(dt)``), so the model is deterministic and testable.
Quaternions are (x, y, z, w), as in geometry_msgs and planner.assembly.
"""
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


def _require(condition: bool, parameter: str, value, expectation: str) -> None:
    if not condition:
        raise ValueError(f"{parameter}={value!r}: {expectation}")


@dataclass(frozen=True)
class Pose:
    """Tool pose: position [m] and unit quaternion (x, y, z, w)."""

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    def __post_init__(self):
        position = tuple(float(v) for v in self.position)
        orientation = tuple(float(v) for v in self.orientation)
        _require(len(position) == 3 and all(map(math.isfinite, position)), "position", self.position,
                 "three finite numbers [m]")
        _require(len(orientation) == 4 and all(map(math.isfinite, orientation)), "orientation",
                 self.orientation, "four finite numbers (x, y, z, w)")
        norm = math.sqrt(sum(v * v for v in orientation))
        _require(abs(norm - 1.0) < 1e-3, "orientation", self.orientation, "a unit quaternion (x, y, z, w)")
        object.__setattr__(self, "position", position)
        object.__setattr__(self, "orientation", tuple(v / norm for v in orientation))

    def distance_to(self, other: "Pose") -> float:
        """Straight-line distance between the positions [m]."""
        return float(np.linalg.norm(np.subtract(other.position, self.position)))

    def angle_to(self, other: "Pose") -> float:
        """Rotation angle between the orientations [rad]."""
        delta = Rotation.from_quat(self.orientation).inv() * Rotation.from_quat(other.orientation)
        return float(delta.magnitude())


@dataclass(frozen=True)
class ArmLimits:
    """Motion limits and the tolerance within which a target counts as reached."""

    max_speed_m_per_s: float = 0.25
    max_acceleration_m_per_s2: float = 0.5
    max_angular_speed_rad_per_s: float = 1.0
    max_angular_acceleration_rad_per_s2: float = 2.0
    position_tolerance_m: float = 1e-3
    orientation_tolerance_rad: float = 1e-2

    def __post_init__(self):
        for parameter in ("max_speed_m_per_s", "max_acceleration_m_per_s2", "max_angular_speed_rad_per_s",
                          "max_angular_acceleration_rad_per_s2", "position_tolerance_m", "orientation_tolerance_rad"):
            value = getattr(self, parameter)
            _require(isinstance(value, (int, float)) and math.isfinite(value) and value > 0,
                     parameter, value, "finite number > 0")


class _Segment:
    """One straight move from ``start`` to ``end`` along s in [0, 1] with a trapezoidal rate profile.

    The rate ds/dt starts at ``initial_rate``, rises (or stays) at ``acceleration_limit`` up to a peak of
    at most ``rate_limit``, cruises, and brakes at ``acceleration_limit`` to rest exactly at s = 1.
    """

    def __init__(self, start: Pose, end: Pose, rate_limit: float, acceleration_limit: float,
                 initial_rate: float = 0.0):
        self.start, self.end = start, end
        self.slerp = Slerp([0.0, 1.0], Rotation.from_quat([start.orientation, end.orientation]))
        accel = self.acceleration = acceleration_limit
        # A start rate too high to brake within the segment is cut to the highest one that can.
        v0 = min(initial_rate, rate_limit, math.sqrt(2.0 * accel))
        peak = min(rate_limit, math.sqrt(accel + 0.5 * v0 * v0))
        self.v0, self.peak = v0, peak
        self.t_accel = (peak - v0) / accel
        self.s_accel = (peak * peak - v0 * v0) / (2.0 * accel)
        s_brake = peak * peak / (2.0 * accel)
        self.s_cruise_end = max(self.s_accel, 1.0 - s_brake)
        self.t_brake = self.t_accel + (self.s_cruise_end - self.s_accel) / peak
        self.duration = self.t_brake + peak / accel
        self.elapsed = 0.0

    def at(self, t: float) -> tuple[float, float]:
        """Path parameter s and its rate at ``t`` seconds into the segment."""
        accel = self.acceleration
        if t >= self.duration:
            return 1.0, 0.0
        if t < self.t_accel:
            return self.v0 * t + 0.5 * accel * t * t, self.v0 + accel * t
        if t < self.t_brake:
            return self.s_accel + self.peak * (t - self.t_accel), self.peak
        tau = t - self.t_brake
        return min(1.0, self.s_cruise_end + self.peak * tau - 0.5 * accel * tau * tau), self.peak - accel * tau

    @property
    def s(self) -> float:
        return self.at(self.elapsed)[0]

    @property
    def rate(self) -> float:
        return self.at(self.elapsed)[1]

    def pose_at(self, s: float) -> Pose:
        position = np.add(self.start.position, s * np.subtract(self.end.position, self.start.position))
        return Pose(tuple(position), tuple(self.slerp([s]).as_quat()[0]))


class SimulatedArm:
    """Kinematic arm: ``move_to`` sets a target, ``step(dt)`` advances time, ``stop`` brakes."""

    def __init__(self, initial_pose: Pose = Pose(), limits: ArmLimits = ArmLimits()):
        self.limits = limits
        self._pose = initial_pose
        self._segment: _Segment | None = None

    @property
    def pose(self) -> Pose:
        return self._pose

    @property
    def target(self) -> Pose | None:
        """Where the running move ends (None when idle)."""
        return None if self._segment is None else self._segment.end

    @property
    def moving(self) -> bool:
        return self._segment is not None

    def speed(self) -> float:
        """Present linear speed of the tool [m/s]."""
        if self._segment is None:
            return 0.0
        return self._segment.rate * self._segment.start.distance_to(self._segment.end)

    def move_to(self, target: Pose, max_speed_m_per_s: float = 0.0) -> None:
        """Start a straight move from the present pose to ``target``.

        max_speed_m_per_s: linear speed limit of this move [m/s]; 0 = the arm's limit. Never above the limit.
        A move started while another runs keeps the present linear speed (no velocity jump).
        """
        _require(isinstance(target, Pose), "target", target, "a Pose")
        limit = max_speed_m_per_s
        _require(isinstance(limit, (int, float)) and math.isfinite(limit) and limit >= 0,
                 "max_speed_m_per_s", limit, "finite number >= 0 (0 = the arm's limit)")
        speed = self.limits.max_speed_m_per_s if limit == 0 else min(limit, self.limits.max_speed_m_per_s)
        distance, angle = self._pose.distance_to(target), self._pose.angle_to(target)
        if self.reached(target):
            self._pose, self._segment = target, None
            return
        # ds/dt and d2s/dt2 limits: the linear and the angular limit each bound them, the tighter one wins.
        rate_limits, acceleration_limits = [], []
        if distance > 0:
            rate_limits.append(speed / distance)
            acceleration_limits.append(self.limits.max_acceleration_m_per_s2 / distance)
        if angle > 0:
            rate_limits.append(self.limits.max_angular_speed_rad_per_s / angle)
            acceleration_limits.append(self.limits.max_angular_acceleration_rad_per_s2 / angle)
        rate, acceleration = min(rate_limits), min(acceleration_limits)
        # A target too far for the speed (or a speed too low for the distance) underflows to a rate of 0:
        # a move that never ends and cannot be timed.
        _require(rate > 0 and acceleration > 0, "target", target,
                 f"a move of finite duration ({distance:.3g} m at up to {speed:.3g} m/s cannot be timed)")
        initial_rate = self.speed() / distance if distance > 0 else 0.0
        self._segment = _Segment(self._pose, target, rate, acceleration, initial_rate)

    def stop(self) -> None:
        """Brake at the allowed deceleration and hold where the tool comes to rest."""
        segment = self._segment
        if segment is None:
            return
        s, rate = segment.s, segment.rate
        stop_s = min(1.0, s + rate * rate / (2.0 * segment.acceleration))
        if stop_s <= s:
            self._segment = None
            return
        # The remaining stretch up to the braking point, re-parameterised to s in [0, 1].
        scale = stop_s - s
        self._segment = _Segment(self._pose, segment.pose_at(stop_s), rate / scale,
                                 segment.acceleration / scale, initial_rate=rate / scale)

    def reached(self, target: Pose) -> bool:
        """Whether the present pose is within the position and orientation tolerance of ``target``."""
        return (self._pose.distance_to(target) <= self.limits.position_tolerance_m
                and self._pose.angle_to(target) <= self.limits.orientation_tolerance_rad)

    def step(self, dt: float) -> Pose:
        """Advance the motion by ``dt`` seconds and return the new pose."""
        _require(isinstance(dt, (int, float)) and math.isfinite(dt) and dt >= 0, "dt", dt, "finite number >= 0")
        segment = self._segment
        if segment is None or dt == 0:
            return self._pose
        segment.elapsed += dt
        self._pose = segment.pose_at(segment.s)
        if segment.s >= 1.0:
            self._pose, self._segment = segment.end, None
        return self._pose

"""Simulated arm node: action `arm/move` (MoveArm) and `arm/pose` (PoseStamped) at `publish_rate_hz`.

The motion model is sim_fallback.arm (straight line, trapezoidal speed, slerped orientation). A real
arm is bridged by serving the same action and topic (see docs/sequences.md). The goal accepted last
preempts the running one; a cancel brakes the arm to rest and holds. Targets must be in `frame_id` (no TF).
"""
import threading
import time

from geometry_msgs.msg import Pose as PoseMsg
from geometry_msgs.msg import PoseStamped
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from sim_fallback.arm import ArmLimits, Pose, SimulatedArm
from softblock_interfaces.action import MoveArm

from .conversions import pose_msg
from .parameters import Param, declare
from .qos import stream_qos
from .runner import run_node

LIMITS = (  # the ArmLimits fields
    Param.of(ArmLimits, "max_speed_m_per_s", "linear speed limit", "m/s", 1e-6, 100.0),
    Param.of(ArmLimits, "max_acceleration_m_per_s2", "linear acceleration limit", "m/s^2", 1e-6, 100.0),
    Param.of(ArmLimits, "max_angular_speed_rad_per_s", "angular speed limit", "rad/s", 1e-6, 100.0),
    Param.of(ArmLimits, "max_angular_acceleration_rad_per_s2", "angular acceleration limit", "rad/s^2", 1e-6, 100.0),
    Param.of(ArmLimits, "position_tolerance_m", "a target counts as reached within this distance", "m", 1e-6, 1.0),
    Param.of(ArmLimits, "orientation_tolerance_rad", "... and within this angle", "rad", 1e-6, 1.0),
)
PARAMETERS = LIMITS + (
    Param("frame_id", "base_link", "frame of poses and targets", kind=str),
    Param("publish_rate_hz", 50.0, "arm/pose rate and simulation step rate", "Hz", 20.0, 1000.0),
    Param("initial_position", [0.45, 0.0, 0.3], "start position (x, y, z)", "m", -10.0, 10.0, size=3),
    Param("initial_orientation", [1.0, 0.0, 0.0, 0.0], "start orientation, quaternion (x, y, z, w)", "", -1.0, 1.0,
          size=4),
)


def to_msg(pose: Pose) -> PoseMsg:
    return pose_msg(pose.position, pose.orientation)


def from_msg(msg: PoseMsg) -> Pose:
    q = msg.orientation
    return Pose((msg.position.x, msg.position.y, msg.position.z), (q.x, q.y, q.z, q.w))


class SimArmNode(Node):
    def __init__(self, **kwargs):
        super().__init__("sim_arm", **kwargs)
        value = declare(self, PARAMETERS)
        self._frame_id = value["frame_id"]
        self._arm = SimulatedArm(Pose(tuple(value["initial_position"]), tuple(value["initial_orientation"])),
                                 ArmLimits(**{param.name: value[param.name] for param in LIMITS}))
        self._lock = threading.Lock()
        self._stepped = threading.Condition(self._lock)
        self._newest_goal = None  # the goal that owns the arm: the one accepted last
        self._refusals = {}  # goal id -> why the goal's target was refused
        self._last_step = time.monotonic()
        self._pose_pub = self.create_publisher(PoseStamped, "arm/pose", stream_qos(value["publish_rate_hz"]))
        self.create_timer(1.0 / value["publish_rate_hz"], self._on_timer)  # default group: one step at a time
        # Requests are handled one at a time, in arrival order, and a goal takes the arm when it is accepted, so
        # the newest goal wins however the executor orders the execute callbacks (they run as tasks, outside
        # this group).
        self._server = ActionServer(self, MoveArm, "arm/move", execute_callback=self._execute,
                                    handle_accepted_callback=self._on_accepted,
                                    cancel_callback=lambda _: CancelResponse.ACCEPT,
                                    callback_group=MutuallyExclusiveCallbackGroup())

    def _on_timer(self) -> None:
        with self._lock:  # the clock is read under the lock: concurrent steps never see time run backwards
            now = time.monotonic()
            pose = self._arm.step(now - self._last_step)
            self._last_step = now
            self._stepped.notify_all()
        msg = PoseStamped(pose=to_msg(pose))
        msg.header.frame_id = self._frame_id
        msg.header.stamp = self.get_clock().now().to_msg()
        self._pose_pub.publish(msg)

    def _on_accepted(self, goal_handle) -> None:
        goal = goal_handle.request
        frame = goal.target.header.frame_id or self._frame_id
        try:
            if frame != self._frame_id:
                raise ValueError(f"target frame {frame!r} is not the arm frame {self._frame_id!r} (no TF here)")
            target = from_msg(goal.target.pose)
            with self._lock:
                self._arm.move_to(target, goal.max_speed)  # [m/s]
                self._newest_goal = goal_handle
        except ValueError as error:  # a refused goal preempts nothing
            self._refusals[bytes(goal_handle.goal_id.uuid)] = str(error)
        goal_handle.execute()

    def _execute(self, goal_handle) -> MoveArm.Result:
        refusal = self._refusals.pop(bytes(goal_handle.goal_id.uuid), None)
        if refusal is not None:
            goal_handle.abort()
            return MoveArm.Result(success=False, message=refusal, final_pose=to_msg(self._arm.pose))
        target = from_msg(goal_handle.request.target.pose)
        stopping = False
        while True:
            with self._lock:
                self._stepped.wait(timeout=0.5)
                pose, moving, preempted = self._arm.pose, self._arm.moving, self._newest_goal is not goal_handle
                if goal_handle.is_cancel_requested and not preempted and not stopping:
                    self._arm.stop()
                    stopping = True
            if preempted:
                goal_handle.abort()
                return MoveArm.Result(success=False, message="preempted by a newer goal", final_pose=to_msg(pose))
            if not moving:
                break
            goal_handle.publish_feedback(MoveArm.Feedback(current_pose=to_msg(pose),
                                                          distance_remaining=pose.distance_to(target)))
        if goal_handle.is_cancel_requested:
            goal_handle.canceled()
            return MoveArm.Result(success=False, message="canceled: arm stopped", final_pose=to_msg(pose))
        with self._lock:
            reached = self._arm.reached(target)
        (goal_handle.succeed if reached else goal_handle.abort)()
        return MoveArm.Result(success=reached, final_pose=to_msg(pose),
                              message="reached" if reached else "stopped short of the target")


def main(args=None) -> int:
    return run_node(SimArmNode, "sim_arm", MultiThreadedExecutor, args=args)


if __name__ == "__main__":
    raise SystemExit(main())

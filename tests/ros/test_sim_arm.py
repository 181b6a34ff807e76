"""Simulated arm node through a real rclpy action client: moves with feedback, publishes arm/pose,
brakes and holds on cancel, a newer goal preempts, bad targets are aborted with the reason."""
import os
import threading

import pytest
import rclpy
from action_msgs.msg import GoalStatus
from geometry_msgs.msg import PoseStamped
from rclpy.parameter import Parameter
from ros_testing import Inbox, wait_for
from waiting import GENEROUS_S
from softblock_interfaces.action import MoveArm
from unique_identifier_msgs.msg import UUID

from softblock_ros.client import ActionClient
from softblock_ros.conversions import pose_msg
from softblock_ros.sim_arm_node import SimArmNode

pytestmark = pytest.mark.integration

DOWN = (1.0, 0.0, 0.0, 0.0)


@pytest.fixture(scope="module")
def arm(ros_context, spin):
    node = SimArmNode(context=ros_context, parameter_overrides=[
        Parameter("max_speed_m_per_s", value=0.5), Parameter("max_acceleration_m_per_s2", value=2.0)])
    client = rclpy.create_node("sim_arm_test_client", context=ros_context)
    poses = Inbox(client, PoseStamped, "arm/pose", 100)
    action = ActionClient(client, MoveArm, "arm/move")
    spin(node, client)
    assert action.wait_for_server(timeout_sec=GENEROUS_S)
    return action, poses


def send(action, position, orientation=DOWN, frame_id="base_link", max_speed=0.0, feedback=None):
    goal = MoveArm.Goal(target=PoseStamped(pose=pose_msg(position, orientation)), max_speed=max_speed)
    goal.target.header.frame_id = frame_id
    future = action.send_goal_async(goal, feedback_callback=feedback)
    wait_for(future.done, what="the goal response")
    return future.result()


def result_of(handle):
    future = handle.get_result_async()
    wait_for(future.done, what="the move result")
    return future.result().status, future.result().result


def test_move_reaches_the_target_with_feedback_and_pose_topic(arm):
    action, poses = arm
    feedback = []
    status, result = result_of(send(action, (0.3, 0.1, 0.2), feedback=lambda msg: feedback.append(msg.feedback)))
    assert status == GoalStatus.STATUS_SUCCEEDED and result.success and result.message == "reached"
    final = result.final_pose.position
    assert (final.x, final.y, final.z) == pytest.approx((0.3, 0.1, 0.2))
    remaining = [f.distance_remaining for f in feedback]
    assert remaining and remaining == sorted(remaining, reverse=True)
    latest = poses.wait(lambda msg: abs(msg.pose.position.x - 0.3) < 1e-6)
    assert latest.header.frame_id == "base_link"


# A crawl: a move that takes minutes, so that a cancel or a newer goal lands while it runs however loaded the host
# (how the arm brakes and when it arrives is tested in simulated time: tests/sim_fallback/test_arm.py).
CRAWL_M_PER_S = 0.005


def test_cancel_brakes_and_holds(arm):
    action, poses = arm
    poses.messages.clear()
    start = poses.wait().pose.position.z
    handle = send(action, (0.3, 0.1, 0.8), max_speed=CRAWL_M_PER_S)
    poses.wait(lambda msg: msg.pose.position.z > start + 1e-4)  # under way
    wait_for(handle.cancel_goal_async().done, what="the cancel response")
    status, result = result_of(handle)
    assert status == GoalStatus.STATUS_CANCELED and result.message == "canceled: arm stopped"
    assert start < result.final_pose.position.z < 0.8
    poses.messages.clear()
    held = poses.wait(lambda msg: True)
    assert held.pose == result.final_pose  # holds where it stopped


def test_newer_goal_preempts(arm):
    action, _ = arm
    first = send(action, (0.3, 0.1, 0.9), max_speed=CRAWL_M_PER_S)
    second = send(action, (0.3, 0.1, 0.3))
    assert result_of(first)[1].message == "preempted by a newer goal"
    assert result_of(second)[0] == GoalStatus.STATUS_SUCCEEDED


@pytest.mark.parametrize("kwargs, message", [
    ({"frame_id": "world"}, "target frame 'world' is not the arm frame 'base_link' (no TF here)"),
    ({"orientation": (0.0, 0.0, 0.0, 2.0)}, "orientation=(0.0, 0.0, 0.0, 2.0): a unit quaternion"),
    ({"max_speed": -1.0}, "max_speed_m_per_s=-1.0: finite number >= 0"),
])
def test_bad_targets_are_aborted_with_the_reason(arm, kwargs, message):
    action, _ = arm
    status, result = result_of(send(action, (0.3, 0.0, 0.3), **kwargs))
    assert status == GoalStatus.STATUS_ABORTED and not result.success
    assert message in result.message


def test_simulation_steps_from_several_threads_never_see_time_run_backwards(ros_context):
    node = SimArmNode(context=ros_context)
    errors = []

    def step_many():
        try:
            for _ in range(300):
                node._on_timer()
        except Exception as error:  # noqa: BLE001 - collected and asserted below
            errors.append(error)

    threads = [threading.Thread(target=step_many) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    node.destroy_node()
    assert errors == []


class ScriptedGoalHandle:
    """A goal handle the test drives by hand, to order acceptance and execution as a loaded executor might."""

    def __init__(self, position, max_speed=0.0):
        self.request = MoveArm.Goal(target=PoseStamped(pose=pose_msg(position, DOWN)), max_speed=max_speed)
        self.goal_id = UUID(uuid=list(os.urandom(16)))
        self.is_cancel_requested = False
        self.outcome = None

    def execute(self):
        pass  # the test runs the execute callback itself

    def publish_feedback(self, feedback):
        pass

    def succeed(self):
        self.outcome = "succeeded"

    def abort(self):
        self.outcome = "aborted"


def test_the_goal_accepted_last_wins_whichever_execute_callback_starts_first(ros_context):
    """Under load, the executor can start the older goal's execute callback after the newer one's: the arm must
    still follow the order of acceptance."""
    node = SimArmNode(context=ros_context)
    older, newer = ScriptedGoalHandle((0.45, 0.0, 0.9), max_speed=CRAWL_M_PER_S), ScriptedGoalHandle((0.45, 0.0, 0.3))
    for handle in (older, newer):
        node._server._handle_accepted_callback(handle)
    results = {}
    stepping = threading.Event()

    def step():
        while not stepping.is_set():
            node._on_timer()
            stepping.wait(0.01)

    def execute(handle):
        results[handle] = node._server._execute_callback(handle)

    stepper = threading.Thread(target=step)
    stepper.start()
    try:
        for handle in (newer, older):  # the newer goal's callback starts first
            runner = threading.Thread(target=execute, args=(handle,), daemon=True)
            runner.start()
            runner.join(timeout=GENEROUS_S)
            assert not runner.is_alive(), f"the goal to z={handle.request.target.pose.position.z} never finished"
    finally:
        stepping.set()
        stepper.join()
        node.destroy_node()
    assert (newer.outcome, results[newer].message) == ("succeeded", "reached")
    assert (older.outcome, results[older].message) == ("aborted", "preempted by a newer goal")

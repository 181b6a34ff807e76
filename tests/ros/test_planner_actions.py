"""The planner's long work as actions, through real rclpy action clients: finger design with progress (the
same fingers as the service) and cancel; a reconfiguration plan from the robot on assembly/current with its
Pareto set and operator steps; per-object settings; a trunk along a path; a canceled plan; a bad goal refused
with the reason (the node carries on)."""
import math
import threading

import numpy as np
import pytest
import rclpy
from action_msgs.msg import GoalStatus
from geometry_msgs.msg import Point
from rclpy.parameter import Parameter
from ros_testing import call
from waiting import GENEROUS_S
from softblock_interfaces.action import DesignFingers, PlanReconfiguration
from softblock_interfaces.srv import DesignFingers as DesignFingersService

from planner.assembly import Assembly, Chain, PlacedBlock
from planner.contours import load_catalog_object
from planner.reconfigure import FingerSlot, TargetObject, plan_reconfiguration
from planner.table import load_table
from softblock_ros.client import ActionClient, run_action
from softblock_ros.conversions import assembly_msg, image_msg
from softblock_ros.planner_node import PlannerNode
from softblock_ros.qos import LATCHED

pytestmark = pytest.mark.integration

TABLE = load_table()
ROBOT = Assembly("pair", (Chain("left", "main", tuple(PlacedBlock(i) for i in (78, 27, 64))),
                          Chain("right", "main", tuple(PlacedBlock(i) for i in (19, 45, 2)))))


@pytest.fixture(scope="module")
def client(ros_context, spin):
    node = PlannerNode(context=ros_context, parameter_overrides=[Parameter("max_blocks", value=6),
                                                                 Parameter("prepare_finger_search", value=False)])
    client = rclpy.create_node("planner_action_client", context=ros_context)
    publisher = client.create_publisher(type(assembly_msg(ROBOT, TABLE)), "assembly/current", LATCHED)
    publisher.publish(assembly_msg(ROBOT, TABLE))
    spin(node, client)
    return client


def fingers_goal(kind, **fields):
    goal = kind(image_path="config/objects/strawberry.png", pixel_size=2.5e-4, num_blocks=2, method="exact",
                time_budget=120.0)
    goal.image = image_msg(np.zeros((0, 0), dtype=np.uint8))
    for name, value in fields.items():
        setattr(goal, name, value)
    return goal


def plan_goal(**fields):
    goal = PlanReconfiguration.Goal(shelf_ids=[2, 14, 40, 71], shelf_counts=[1, 1, 2, 1],
                                    object_image_paths=["config/objects/strawberry.png"], pixel_sizes=[2.5e-4],
                                    finger_chains=["left", "right"], finger_sides=["left", "right"],
                                    finger_stiff_top=[0, 0], time_budget=300.0, max_swaps=-1)
    for name, value in fields.items():
        setattr(goal, name, value)
    return goal


def test_finger_design_action_reports_progress_and_matches_the_service(client):
    feedback = []
    status, result = run_action(ActionClient(client, DesignFingers, "planner/design_fingers"),
                                fingers_goal(DesignFingers.Goal), 180.0, lambda f: feedback.append(f.feedback))
    assert status == GoalStatus.STATUS_SUCCEEDED and result.success and result.optimal, result.message
    assert feedback and all(0.0 <= f.fraction <= 1.0 and f.elapsed >= 0.0 for f in feedback)
    reply = call(client.create_client(DesignFingersService, "planner/design_fingers"),
                 fingers_goal(DesignFingersService.Request), timeout=180.0)
    assert reply.success and [b.design.id for b in reply.left.blocks] == [b.design.id for b in result.left.blocks]
    assert result.left_cost == pytest.approx(reply.left_cost, abs=1e-12)


def send_and_cancel(client, kind, name, goal):
    """Send a goal, cancel it at its first feedback; returns (status, result)."""
    action = ActionClient(client, kind, name)
    assert action.wait_for_server(timeout_sec=GENEROUS_S)
    handle_box, canceled = [], threading.Event()

    def on_feedback(_):
        if handle_box and not canceled.is_set():
            canceled.set()
            handle_box[0].cancel_goal_async()

    sent = action.send_goal_async(goal, feedback_callback=on_feedback)
    done = threading.Event()
    sent.add_done_callback(lambda _: done.set())
    assert done.wait(30.0)
    handle_box.append(sent.result())
    finished = threading.Event()
    result = handle_box[0].get_result_async()
    result.add_done_callback(lambda _: finished.set())
    assert finished.wait(300.0), "no result after the cancel"
    return result.result().status, result.result().result


def test_finger_design_action_can_be_canceled(client):
    status, result = send_and_cancel(client, DesignFingers, "planner/design_fingers",
                                     fingers_goal(DesignFingers.Goal, num_blocks=6, method="pso", time_budget=600.0))
    assert status == GoalStatus.STATUS_CANCELED and not result.optimal
    assert "canceled" in result.message


def test_plan_from_the_built_robot_gives_the_pareto_set_and_steps(client):
    feedback = []
    status, result = run_action(ActionClient(client, PlanReconfiguration, "planner/plan_reconfiguration"),
                                plan_goal(), 600.0, lambda f: feedback.append(f.feedback))
    assert status == GoalStatus.STATUS_SUCCEEDED and result.success, result.message
    assert list(result.max_swaps) == list(range(7)) and feedback
    assert all(lb <= obj + 1e-12 for lb, obj in zip(result.lower_bounds, result.objectives))
    assert all(b <= a + 1e-12 for a, b in zip(result.objectives, result.objectives[1:]))  # more swaps: no worse
    assert len(result.steps) >= result.swaps[-1] and all("position" in step for step in result.steps)
    layout = {c.name: list(c.design_ids) for c in ROBOT.chains}
    for chain, position, insert in zip(result.step_chains, result.step_positions, result.step_insert):
        layout[chain][position] = None if insert < 0 else insert
    assert layout == {c.name: [b.design.id for b in c.blocks] for c in result.target.chains}


def test_each_object_of_a_plan_keeps_its_own_settings(client):
    """Contact tolerance, contour spacing and base offsets per object [m]: the action's plan is the library's
    plan with the same settings."""
    settings = dict(contact_tolerances=[0.0, 3e-4], contour_spacings=[1e-3, 1.5e-3],
                    base_offsets=[0.0, 2e-3, 4e-3, 1e-3], base_offset_counts=[3, 1])
    goal = plan_goal(object_image_paths=["config/objects/strawberry.png", "config/objects/strawberry.png"],
                     pixel_sizes=[2.5e-4, 2.5e-4], weights=[1.0, 0.5], **settings)
    status, result = run_action(ActionClient(client, PlanReconfiguration, "planner/plan_reconfiguration"), goal,
                                600.0)
    assert status == GoalStatus.STATUS_SUCCEEDED and result.success, result.message
    objects = [TargetObject(name, load_catalog_object(name), weight=weight, base_offsets=np.array(offsets),
                            contour_spacing=spacing, contact_tolerance_m=tolerance)
               for name, weight, offsets, spacing, tolerance in zip(
                   ("strawberry", "strawberry"), (1.0, 0.5), ([0.0, 2e-3, 4e-3], [1e-3]), (1e-3, 1.5e-3), (0.0, 3e-4))]
    plan = plan_reconfiguration(ROBOT, {2: 1, 14: 1, 40: 2, 71: 1}, objects,
                                slots=(FingerSlot("left", "left"), FingerSlot("right", "right")))
    assert list(result.objectives) == pytest.approx([p.objective for p in plan.points], abs=1e-9)


def test_a_trunk_plan_follows_its_path(client):
    """A path target [m] for one chain: its Pareto set from the chain as built (rotations included) and the
    steps that rebuild the chosen chain."""
    t = np.linspace(0.0, 1.0, 10)
    path = [Point(x=0.012 * (1 - math.cos(2 * s)), y=0.012 * math.sin(2 * s), z=0.06 * s) for s in t]
    goal = plan_goal(object_image_paths=[], pixel_sizes=[], finger_chains=[], finger_sides=[], finger_stiff_top=[],
                     path=path, path_chain="left", max_swaps=2)
    status, result = run_action(ActionClient(client, PlanReconfiguration, "planner/plan_reconfiguration"), goal,
                                600.0)
    assert status == GoalStatus.STATUS_SUCCEEDED and result.success, result.message
    assert list(result.max_swaps) == [0, 1, 2, 3] and all(result.optimal)
    assert all(b <= a + 1e-12 for a, b in zip(result.objectives, result.objectives[1:]))
    left = [b for c in result.target.chains if c.name == "left" for b in c.blocks]
    assert result.swaps[2] <= 2 and len(result.steps) >= result.swaps[2]
    layout = {c.name: list(c.design_ids) for c in ROBOT.chains}
    for chain, position, insert in zip(result.step_chains, result.step_positions, result.step_insert):
        layout[chain][position] = None if insert < 0 else insert
    assert layout["left"] == [b.design.id for b in left] and layout["right"] == list(ROBOT.chain("right").design_ids)


def test_a_canceled_plan_keeps_its_bounds(client):
    goal = plan_goal(object_image_paths=["config/objects/strawberry.png", "config/objects/gingerbread.png"],
                     pixel_sizes=[2.5e-4, 2.5e-4], weights=[1.0, 1.0])
    status, result = send_and_cancel(client, PlanReconfiguration, "planner/plan_reconfiguration", goal)
    assert status == GoalStatus.STATUS_CANCELED and "canceled" in result.message
    assert all(lb <= obj or math.isinf(lb) for lb, obj in zip(result.lower_bounds, result.objectives))


def test_a_bad_plan_goal_is_refused_with_the_reason(client):
    # One action client for the seven goals (seen once in `make test`, each goal then having a client of its own: a
    # 10 s timeout on the second goal; a new client could then be taken from before it was whole, see
    # softblock_ros.client.ActionClient).
    action = ActionClient(client, PlanReconfiguration, "planner/plan_reconfiguration")
    status, result = run_action(action, plan_goal(finger_sides=["left", "up"]), 60.0)
    assert status == GoalStatus.STATUS_ABORTED and not result.success
    assert "side must be one of" in result.message
    for fields, reason in ((dict(pixel_sizes=[]), "pixel_sizes"),
                           (dict(contact_tolerances=[0.0, 0.0]), "contact_tolerances must have one entry per object"),
                           (dict(base_offsets=[0.0, 1e-3]), "base_offsets need base_offset_counts"),
                           (dict(base_offsets=[0.0], base_offset_counts=[2]), "add up to the 1 base_offsets"),
                           (dict(path=[Point(z=0.01), Point(z=0.02)], path_chain="left"), "not both"),
                           (dict(object_image_paths=[], pixel_sizes=[], finger_chains=[], path_chain="left",
                                 path=[Point(z=0.01)]), "path must be an (n, 3) array")):
        status, result = run_action(action, plan_goal(**fields), 60.0)
        assert status == GoalStatus.STATUS_ABORTED and reason in result.message, (fields, result.message)

"""Planner node through real rclpy clients: finger design from a file and from an image message, bad
requests refused with a clear message (the node carries on), a DesignPath round trip, and other requests
answered while a long optimization runs."""
import math
import threading
from collections import OrderedDict

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import Point
from rcl_interfaces.srv import GetParameters
from rclpy.parameter import Parameter
from ros_testing import call, wait_for
from waiting import GENEROUS_S
from softblock_interfaces.srv import DesignFingers, DesignPath

import planner.design
from planner.kinematics import chain_shape
from planner.optimize import lookahead
from planner.table import load_table
from softblock_ros.conversions import BLOCK_DESIGN_FIELDS, image_msg
from softblock_ros.planner_node import PlannerNode

pytestmark = pytest.mark.integration

MAX_BLOCKS = 6
TABLE = load_table()


@pytest.fixture(scope="module")
def client(ros_context, spin):
    node = PlannerNode(context=ros_context, parameter_overrides=[Parameter("max_blocks", value=MAX_BLOCKS)])
    client = rclpy.create_node("planner_test_client", context=ros_context)
    spin(node, client)
    return client


def object_mask(height=120, width=80) -> np.ndarray:
    """A pear-like blob well inside the image: object 255, background 0."""
    rows, cols = np.mgrid[:height, :width]
    radius = 18 + 10 * np.sin(np.pi * (rows - 10) / 100)
    mask = (np.abs(cols - width / 2) < radius) & (rows > 10) & (rows < 110)
    return np.where(mask, 255, 0).astype(np.uint8)


def fingers_request(**fields) -> DesignFingers.Request:
    request = DesignFingers.Request(pixel_size=0.0005, num_blocks=2, method="exact", time_budget=60.0)
    request.image = image_msg(object_mask())
    for name, value in fields.items():
        setattr(request, name, value)
    return request


def design_fingers(client, request):
    return call(client.create_client(DesignFingers, "planner/design_fingers"), request, timeout=120.0)


def design_path(client, request):
    return call(client.create_client(DesignPath, "planner/design_path"), request, timeout=120.0)


def assert_blocks_from_table(chain, count):
    assert len(chain.blocks) == count
    for block in chain.blocks:
        row = TABLE.design(block.design.id)
        for name in BLOCK_DESIGN_FIELDS:
            assert getattr(block.design, name) == pytest.approx(getattr(row, name)), name


def test_fingers_for_an_image_message(client):
    reply = design_fingers(client, fingers_request())
    assert reply.success, reply.message
    for chain, cost in ((reply.left, reply.left_cost), (reply.right, reply.right_cost)):
        assert_blocks_from_table(chain, 2)
        assert math.isfinite(cost) and cost >= 0.0
    assert (reply.left.name, reply.right.name) == ("left", "right")
    # Finger bases sit beside the object (object frame: origin at its top centre, x right, z up),
    # oriented to grow downward and bend toward it.
    assert reply.left.base_pose.position.x < 0.0 < reply.right.base_pose.position.x
    left_q, right_q = reply.left.base_pose.orientation, reply.right.base_pose.orientation
    assert (left_q.x, left_q.y, left_q.z, left_q.w) == (1.0, 0.0, 0.0, 0.0)
    assert (right_q.x, right_q.y, right_q.z, right_q.w) == (0.0, 1.0, 0.0, 0.0)


def test_fingers_for_a_sample_object_file_with_stiff_top_blocks(client):
    request = fingers_request(image_path="config/objects/gingerbread.png", pixel_size=0.00025, num_blocks=2,
                              num_stiff_top=1, min_stiff_rod_diameter=0.00062, time_budget=90.0)
    request.image = image_msg(np.zeros((0, 0), dtype=np.uint8))
    reply = design_fingers(client, request)
    assert reply.success, reply.message
    for chain in (reply.left, reply.right):
        assert_blocks_from_table(chain, 2)
        assert chain.blocks[0].design.rod_diameter >= 0.00062 - 1e-9


def test_gripper_designs_arrive_within_their_timeout(client):
    """The demo's gripper: front fingers of 4 blocks (top 2 stiff), back fingers of 5 (top 3 stiff) around
    the asymmetric sample object, each pair with a 2 s budget; the replies carry clearances and bounds."""
    for blocks, stiff in ((4, 2), (5, 3)):
        request = fingers_request(image_path="config/objects/asymmetric.png", pixel_size=0.00025, num_blocks=blocks,
                                  num_stiff_top=stiff, min_stiff_rod_diameter=0.00062, time_budget=2.0)
        request.image = image_msg(np.zeros((0, 0), dtype=np.uint8))
        reply = call(client.create_client(DesignFingers, "planner/design_fingers"), request, timeout=120.0)
        assert reply.success, reply.message
        for side in ("left", "right"):
            assert_blocks_from_table(getattr(reply, side), blocks)
            assert not getattr(reply, f"{side}_collision")
            assert getattr(reply, f"{side}_min_clearance") >= -2e-6
            assert getattr(reply, f"{side}_lower_bound") <= getattr(reply, f"{side}_cost")
        assert reply.optimal or "lower bound" in reply.message


@pytest.mark.parametrize("max_blocks, prepare, loaded", [(4, True, 2), (2, True, 1), (4, False, 0)])
def test_the_node_prepares_the_finger_search_before_it_serves(ros_context, monkeypatch, max_blocks, prepare, loaded):
    """Once the node is up, the lookahead fields of the small problem that compiles the search and of the
    gripper's configurations within max_blocks (4 blocks: only (4, 2)) are in memory, so the first request
    does not load them (seconds)."""
    monkeypatch.setattr(lookahead, "_LOADED", OrderedDict())
    node = PlannerNode(context=ros_context, parameter_overrides=[
        Parameter("max_blocks", value=max_blocks), Parameter("prepare_finger_search", value=prepare)])
    try:
        assert len(lookahead._LOADED) == loaded
    finally:
        node.destroy_node()


def test_contact_tolerance_lets_the_body_enter_the_object(client):
    strict = design_fingers(client, fingers_request())
    tolerant = design_fingers(client, fingers_request(contact_tolerance=0.002))
    assert strict.success and tolerant.success
    assert min(strict.left_min_clearance, strict.right_min_clearance) >= -2e-6
    assert min(tolerant.left_min_clearance, tolerant.right_min_clearance) >= -0.002 - 2e-6
    assert tolerant.left_cost + tolerant.right_cost <= strict.left_cost + strict.right_cost + 1e-9
    refused = design_fingers(client, fingers_request(contact_tolerance=-0.001))
    assert not refused.success and "contact_tolerance" in refused.message


def blank():
    return np.zeros((40, 40), dtype=np.uint8)


def three_levels():
    mask = object_mask()
    mask[50:60, 30:50] = 128
    return mask


def touching_border():
    mask = object_mask()
    mask[60:, 35:45] = 255  # a stalk down to the bottom edge
    return mask


def two_objects():
    mask = np.zeros((60, 60), dtype=np.uint8)
    mask[10:50, 10:25] = mask[10:50, 35:50] = 255
    return mask


@pytest.mark.parametrize("fields, problem", [
    (dict(image=image_msg(blank())), "object image is empty"),
    (dict(image=image_msg(three_levels())), "object image is not binary (3 grey levels)"),
    (dict(image=image_msg(touching_border())), "object touches the image border"),
    (dict(image=image_msg(two_objects())), "object image holds 2 objects"),
    (dict(pixel_size=0.0), "pixel_size must be a positive number"),
    (dict(pixel_size=1e300), "pixel_size must be a positive number of m/pixel in 1e-06..0.01, got 1e+300"),
    (dict(pixel_size=1e-300), "pixel_size must be a positive number of m/pixel in 1e-06..0.01, got 1e-300"),
    (dict(num_blocks=0), f"num_blocks must be 1..{MAX_BLOCKS}, got 0"),
    (dict(num_blocks=MAX_BLOCKS + 1), f"num_blocks must be 1..{MAX_BLOCKS}, got {MAX_BLOCKS + 1}"),
    (dict(method="simplex"), "method must be one of exact, pso, got 'simplex'"),
    (dict(time_budget=-1.0), "time_budget must be >= 0 s, got -1.0"),
    (dict(image=image_msg(np.zeros((0, 0), dtype=np.uint8))), "give an image or an image_path"),
    (dict(image=image_msg(np.zeros((0, 0), dtype=np.uint8)), image_path="/nonexistent/object.png"),
     "cannot read object image /nonexistent/object.png"),
    (dict(inventory_ids=[57, 15], inventory_counts=[4]), "inventory_ids has 2 entries but inventory_counts has 1"),
])
def test_bad_finger_requests_are_refused_and_the_node_carries_on(client, fields, problem):
    reply = design_fingers(client, fingers_request(**fields))
    assert not reply.success
    assert problem in reply.message
    assert reply.message.startswith("request refused: ")


def test_a_failure_inside_the_design_code_is_answered_too(client, monkeypatch):
    def broken(*args, **kwargs):
        raise TypeError("`pad_width` must be of integral type.")

    monkeypatch.setattr(planner.design, "design_path", broken)
    request = DesignPath.Request(path=[Point(x=0.0, y=0.0, z=0.01 * i) for i in range(5)], num_blocks=2,
                                 time_budget=5.0)
    reply = design_path(client, request)
    assert not reply.success
    assert reply.message == "request failed: TypeError: `pad_width` must be of integral type."
    monkeypatch.undo()
    assert design_path(client, request).success  # and the node still serves


def test_wrong_image_encoding_is_refused(client):
    request = fingers_request()
    request.image.encoding = "rgb8"
    reply = design_fingers(client, request)
    assert not reply.success and "image encoding must be mono8, got 'rgb8'" in reply.message


def chain_path(design_ids, rotation_steps):
    """Centerline of a chain of table designs at 0 V, as path points."""
    theta = [TABLE.design(i).theta0 for i in design_ids]
    length = [TABLE.design(i).rod_length for i in design_ids]
    shape = chain_shape(theta, length, np.radians(30.0) * np.array(rotation_steps))
    return [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in shape.points]


def test_design_path_round_trip_recovers_a_chain_along_its_own_centerline(client):
    request = DesignPath.Request(path=chain_path([15, 57, 15], [0, 3, 0]), num_blocks=3, allow_rotation=True,
                                 method="exact", time_budget=60.0)
    reply = design_path(client, request)
    assert reply.success, reply.message
    assert_blocks_from_table(reply.chain, 3)
    assert reply.cost < 1e-3
    assert [b.rotation for b in reply.chain.blocks][1] != 0.0


def test_path_with_nan_is_refused(client):
    path = chain_path([15, 15], [0, 0])
    path[3].y = math.nan
    reply = design_path(client, DesignPath.Request(path=path, num_blocks=2, method="exact"))
    assert not reply.success
    assert "path point 3 is not finite" in reply.message


def test_other_requests_are_answered_while_an_optimization_runs(client, monkeypatch):
    started, release = threading.Event(), threading.Event()
    real_design_fingers = planner.design.design_fingers

    def long_design_fingers(*args, **kwargs):
        started.set()
        release.wait(60.0)
        return real_design_fingers(*args, **kwargs)

    monkeypatch.setattr(planner.design, "design_fingers", long_design_fingers)
    fingers_client = client.create_client(DesignFingers, "planner/design_fingers")
    assert fingers_client.wait_for_service(timeout_sec=GENEROUS_S)
    long_request = fingers_client.call_async(fingers_request(num_blocks=1))
    try:
        wait_for(started.is_set, what="the optimization to start")
        parameters = call(client.create_client(GetParameters, "planner/get_parameters"),
                          GetParameters.Request(names=["max_blocks"]))
        assert parameters.values[0].integer_value == MAX_BLOCKS
        path_reply = design_path(client, DesignPath.Request(path=chain_path([15], [0]), num_blocks=1,
                                                            method="exact"))
        assert path_reply.success, path_reply.message
        assert not long_request.done()
    finally:
        release.set()
    reply = wait_for(lambda: long_request.done() and long_request.result(), timeout=120.0,
                     what="the long request to finish")
    assert reply.success, reply.message


@pytest.mark.parametrize("stop", ["destroy_node", "context shutdown"])
def test_stopping_the_node_cancels_a_running_optimization(monkeypatch, stop):
    """A request without a time limit runs until the node stops: a stop signal shuts the process's context down
    (tests/ros/test_runner.py), then the runner destroys the node. Either ends the search at its next progress
    report, and the request is answered as canceled. The search is held at its first report until the stop."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = PlannerNode(context=context, parameter_overrides=[Parameter("prepare_finger_search", value=False),
                                                             Parameter("default_time_budget_s", value=0.0)])
    searching, stopped = threading.Event(), threading.Event()
    real_design_fingers = planner.design.design_fingers

    def held_at_its_first_report(*args, callback, **kwargs):
        def report(progress):
            searching.set()
            stopped.wait(60.0)
            callback(progress)

        return real_design_fingers(*args, callback=report, **kwargs)

    monkeypatch.setattr(planner.design, "design_fingers", held_at_its_first_report)
    response = DesignFingers.Response()
    worker = threading.Thread(target=node._serve, args=(node._design_fingers, fingers_request(time_budget=0.0),
                                                        response))
    worker.start()
    try:
        wait_for(searching.is_set, what="the search's first progress report")
        if stop == "destroy_node":
            node.destroy_node()
        else:
            context.shutdown()
    finally:
        stopped.set()
        worker.join(timeout=60.0)
        rclpy.try_shutdown(context=context)
    assert not worker.is_alive()
    assert not response.success
    assert "left: canceled" in response.message and "right: canceled" in response.message

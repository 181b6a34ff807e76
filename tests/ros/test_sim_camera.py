"""The demo's camera wiring: the simulated camera draws the current assembly's chain at the measured voltage with
its blocks perturbed, and the estimator, with the same view parameters, recovers those perturbations."""
import math

import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from rclpy.time import Time
from ros_testing import Inbox, wait_for
from sensor_msgs.msg import Image
from softblock_interfaces.msg import Assembly, AssemblyState, HvChannelState, HvState

from planner.assembly import Assembly as CoreAssembly
from planner.assembly import Chain, PlacedBlock
from planner.table import load_table
from softblock_ros.conversions import assembly_msg, mask_from_image
from softblock_ros.estimator_node import EstimatorNode
from softblock_ros.qos import LATCHED
from softblock_ros.sim_camera_node import SimCameraNode

pytestmark = pytest.mark.integration

OFFSETS = [0.03, -0.02, 0.025]  # [rad]
VOLTAGE = 1500.0  # [V]
VIEW = [Parameter("chain", value="finger"), Parameter("base_pose", value=[0.05, 0.005, math.pi / 2])]
FINGER = Chain("finger", "front", (PlacedBlock(15), PlacedBlock(15), PlacedBlock(22)))


@pytest.fixture(scope="module")
def nodes(ros_context, spin):
    camera = SimCameraNode(context=ros_context, parameter_overrides=VIEW + [
        Parameter("rate_hz", value=5.0), Parameter("block_offsets_rad", value=OFFSETS + [0.05])])
    estimator = EstimatorNode(context=ros_context, parameter_overrides=VIEW)
    client = rclpy.create_node("sim_camera_test_client", context=ros_context)
    spin(camera, estimator, client)
    return camera, estimator, client


def test_the_estimator_recovers_the_simulated_perturbation_from_the_cameras_image(nodes):
    camera, estimator, client = nodes
    images = Inbox(client, Image, "camera/silhouette")
    estimates = Inbox(client, AssemblyState, "assembly/estimated")
    # The camera and the estimator read hv/state each on their own (as a real camera would); the scene is
    # shown once both know the voltage, so the image is drawn and estimated at the same one.
    hv = client.create_publisher(HvState, "hv/state", qos_profile_sensor_data)
    channel = HvChannelState(name=FINGER.hv_channel, measured_voltage=VOLTAGE)
    client.create_timer(0.1, lambda: hv.publish(HvState(channels=[channel])))
    wait_for(lambda: camera._voltages.get("front") == estimator._voltages.get("front") == VOLTAGE, 30.0,
             "both nodes to read the voltage")
    client.create_publisher(Assembly, "assembly/current", LATCHED).publish(
        assembly_msg(CoreAssembly("scene", (FINGER,)), load_table()))
    image = images.wait(timeout=60.0)
    assert (image.encoding, image.height, image.width) == ("mono8", 480, 320)
    assert set(np.unique(mask_from_image(image))) == {0, 255}
    drawn = load_table().angle_at(FINGER.design_ids, VOLTAGE)[0] + np.array(OFFSETS)  # the fourth offset: no block
    estimate = estimates.wait(timeout=60.0)
    assert estimate.chains[0].voltage == VOLTAGE
    np.testing.assert_allclose(estimate.chains[0].block_angles, drawn, atol=math.radians(0.5))


def test_a_still_scene_gives_no_new_images(nodes):
    _, _, client = nodes
    images = Inbox(client, Image, "camera/silhouette")
    quiet_until = client.get_clock().now().nanoseconds + 2_000_000_000  # ten camera periods
    wait_for(lambda: client.get_clock().now().nanoseconds > quiet_until, 10.0, "two seconds")
    assert images.messages == []



def test_the_world_assembly_replaces_the_belief_and_a_still_scene_is_repeated_when_asked(ros_context, spin):
    """A swap done wrong: the belief (assembly/current) says design 15 at the tip, the world (sim/assembly_built)
    holds 22 there; the camera draws the world from then on, and with repeat_period_s its still image comes
    again, newly stamped."""
    camera = SimCameraNode(context=ros_context, namespace="/world", parameter_overrides=VIEW + [
        Parameter("rate_hz", value=10.0), Parameter("repeat_period_s", value=0.5)])
    client = rclpy.create_node("world_client", context=ros_context, namespace="/world")
    images = Inbox(client, Image, "camera/silhouette")
    spin(camera, client)
    table = load_table()
    believed = Chain("finger", "front", (PlacedBlock(15), PlacedBlock(15), PlacedBlock(15)))
    belief = client.create_publisher(Assembly, "assembly/current", LATCHED)
    belief.publish(assembly_msg(CoreAssembly("believed", (believed,)), table))
    wait_for(lambda: camera._chain == believed, 30.0, "the camera to draw the belief")
    client.create_publisher(Assembly, "sim/assembly_built", LATCHED).publish(
        assembly_msg(CoreAssembly("built", (FINGER,)), table))
    built = camera._draw(FINGER, 0.0)
    first = images.wait(lambda msg: np.array_equal(mask_from_image(msg), built), timeout=60.0)
    belief.publish(assembly_msg(CoreAssembly("believed again", (believed,)), table))  # no longer decides
    stamp = Time.from_msg(first.header.stamp).nanoseconds
    again = images.wait(lambda msg: Time.from_msg(msg.header.stamp).nanoseconds > stamp + 1_000_000_000, 60.0)
    np.testing.assert_array_equal(mask_from_image(again), built)
    assert camera._chain == FINGER

"""The demo's camera wiring: the simulated camera draws the current assembly's chain at the measured voltage with
its blocks perturbed, and the estimator, with the same view parameters, recovers those perturbations."""
import math

import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
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

"""Simulated camera: a side view of one chain of the current assembly, as a binary silhouette.

The simulated scene's chain is the assembly the simulated world holds at the channel voltage measured on
``hv/state``, each block bent ``block_offsets_rad`` more than the look-up table says (the hand-made blocks
of the real gripper differ a little from their design). The world holds what the stack believes
(``assembly/current``) until an assembly arrives on ``sim/assembly_built`` (latched): what a person actually
built, e.g. a swap done wrong; from then on that one is drawn. Drawn by ``estimation.render`` (the reference
renderer the estimator's tests use) into a fixed ``image_size`` frame and published as mono8 (0 / 255) on
``camera/silhouette`` whenever the scene changed (world assembly or voltage), at most ``rate_hz`` times a second;
with ``repeat_period_s`` > 0 an unchanged scene's image is sent again, newly stamped, after that long, as a
streaming camera would (an operator_swap step waits for an image taken after the operator's confirmation).
The view parameters are the estimator's (``chain``, ``pixel_size_m``, ``base_pose``, ``mirrored``), so the same
parameter file serves both.
"""
from __future__ import annotations

import sys
from functools import partial

import numpy as np
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.time import Time
from sensor_msgs.msg import Image
from softblock_interfaces.msg import Assembly, HvState

from estimation.render import render_chain, to_binary
from planner.table import load_table

from .conversions import assembly_from_msg, channel_voltages, image_msg
from .estimator_node import VIEW_PARAMETERS, camera_view
from .parameters import Param, declare
from .qos import LATCHED, stream_qos
from .runner import run_node

PARAMETERS = VIEW_PARAMETERS + (
    Param("image_size", [480, 320], "image rows and columns", "pixels", 8, 4000, kind=int, size=2),
    Param("rate_hz", 1.0, "most images per second (a new one only when the assembly or the voltage changed)", "Hz",
          0.01, 30.0),
    Param("block_offsets_rad", [], "angle added to each block's table angle, base first (missing: 0)", "rad",
          -0.17, 0.17, size=(0, 64)),
    Param("frame_id", "camera", "frame of the images", kind=str),
    Param("repeat_period_s", 0.0, "an unchanged scene's image is sent again after this long; 0: only on a change",
          "s", 0.0, 3600.0),
)
WORLD_TOPIC = "sim/assembly_built"  # the simulated world's assembly (what was built), when it differs from the belief


class SimCameraNode(Node):
    def __init__(self, **kwargs):
        super().__init__("sim_camera", **kwargs)
        value = declare(self, PARAMETERS)
        self._chain_name, self._pixel_size, pose = camera_view(value)
        self._frame = (pose, tuple(value["image_size"]))
        self._offsets, self._frame_id = np.array(value["block_offsets_rad"], dtype=float), value["frame_id"]
        self._table = load_table()
        self._repeat_ns = int(value["repeat_period_s"] * 1e9)
        self._chain = None
        self._world_given = False  # an assembly came on WORLD_TOPIC: the belief no longer decides the scene
        self._voltages: dict[str, float] = {}
        self._drawn_scene = None  # (chain, voltage) last drawn
        self._last_image: Image | None = None
        # a recorder reads every image: a depth of 1 lost one to a recorder starved under load (nothing left to repair)
        self._image_pub = self.create_publisher(Image, "camera/silhouette", stream_qos(value["rate_hz"]))
        self.create_subscription(Assembly, "assembly/current", partial(self._on_assembly, world=False), LATCHED)
        self.create_subscription(Assembly, WORLD_TOPIC, partial(self._on_assembly, world=True), LATCHED)
        self.create_subscription(HvState, "hv/state", self._on_hv_state, qos_profile_sensor_data)
        self.create_timer(1.0 / value["rate_hz"], self._publish_image)

    def _on_assembly(self, message: Assembly, world: bool) -> None:
        if self._world_given and not world:
            return
        try:
            assembly, _ = assembly_from_msg(message, self._table)
        except ValueError as error:
            self.get_logger().warning(f"assembly refused: {error}")
            return
        if world and not self._world_given:
            self._world_given = True
            self.get_logger().info(f"drawing the world's assembly from {WORLD_TOPIC} from now on")
        self._chain = next((c for c in assembly.chains if c.name == self._chain_name), None)
        if self._chain is None:
            self.get_logger().warning(f"the assembly {assembly.name!r} has no chain {self._chain_name!r}: no images")

    def _on_hv_state(self, message: HvState) -> None:
        self._voltages = channel_voltages(message)

    def _draw(self, chain, voltage: float) -> np.ndarray:
        offsets = np.zeros(len(chain.blocks))
        count = min(len(offsets), len(self._offsets))
        offsets[:count] = self._offsets[:count]
        coverage, _, _ = render_chain(chain.design_ids, [b.rotation_steps for b in chain.blocks], self._table,
                                      self._pixel_size, offsets=offsets, voltage=voltage, frame=self._frame)
        return to_binary(coverage)

    def _publish_image(self) -> None:
        chain = self._chain
        if chain is None:
            return
        scene = (chain, self._voltages.get(chain.hv_channel, 0.0))
        now = self.get_clock().now()
        if scene == self._drawn_scene:  # nothing moved: no new image to draw (a fifth of a second) or estimate
            last = self._last_image
            if not self._repeat_ns or now.nanoseconds - Time.from_msg(last.header.stamp).nanoseconds < self._repeat_ns:
                return
            image = last
        else:
            self._drawn_scene = scene
            image = image_msg(self._draw(*scene))
            image.header.frame_id = self._frame_id
        image.header.stamp = now.to_msg()
        self._last_image = image
        self._image_pub.publish(image)


def main(args=None):
    sys.exit(run_node(SimCameraNode, "sim_camera", args=args))


if __name__ == "__main__":
    main()

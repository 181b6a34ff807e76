"""Simulated camera: a side view of one chain of the current assembly, as a binary silhouette.

The simulated scene's chain is the assembly's (``assembly/current``) at the channel voltage measured on
``hv/state``, each block bent ``block_offsets_rad`` more than the look-up table says (the hand-made blocks
of the real gripper differ a little from their design). Drawn by ``estimation.render`` (the reference renderer
the estimator's tests use) into a fixed ``image_size`` frame and published as mono8 (0 / 255) on
``camera/silhouette`` whenever the scene changed (assembly or voltage), at most ``rate_hz`` times a second. The view parameters are the estimator's (``chain``, ``pixel_size_m``, ``base_pose``,
``mirrored``), so the same parameter file serves both.
"""
from __future__ import annotations

import sys

import numpy as np
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
from softblock_interfaces.msg import Assembly, HvState

from estimation.render import render_chain, to_binary
from planner.table import load_table

from .conversions import assembly_from_msg, channel_voltages, image_msg
from .estimator_node import VIEW_PARAMETERS, camera_view
from .parameters import Param, declare
from .qos import LATCHED
from .runner import run_node

PARAMETERS = VIEW_PARAMETERS + (
    Param("image_size", [480, 320], "image rows and columns", "pixels", 8, 4000, kind=int, size=2),
    Param("rate_hz", 1.0, "most images per second (a new one only when the assembly or the voltage changed)", "Hz",
          0.01, 30.0),
    Param("block_offsets_rad", [], "angle added to each block's table angle, base first (missing: 0)", "rad",
          -0.17, 0.17, size=(0, 64)),
    Param("frame_id", "camera", "frame of the images", kind=str),
)


class SimCameraNode(Node):
    def __init__(self, **kwargs):
        super().__init__("sim_camera", **kwargs)
        value = declare(self, PARAMETERS)
        self._chain_name, self._pixel_size, pose = camera_view(value)
        self._frame = (pose, tuple(value["image_size"]))
        self._offsets, self._frame_id = np.array(value["block_offsets_rad"], dtype=float), value["frame_id"]
        self._table = load_table()
        self._chain = None
        self._voltages: dict[str, float] = {}
        self._drawn_scene = None  # (chain, voltage) last drawn
        self._image_pub = self.create_publisher(Image, "camera/silhouette", 1)
        self.create_subscription(Assembly, "assembly/current", self._on_assembly, LATCHED)
        self.create_subscription(HvState, "hv/state", self._on_hv_state, qos_profile_sensor_data)
        self.create_timer(1.0 / value["rate_hz"], self._publish_image)

    def _on_assembly(self, message: Assembly) -> None:
        try:
            assembly, _ = assembly_from_msg(message, self._table)
        except ValueError as error:
            self.get_logger().warning(f"assembly refused: {error}")
            return
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
        if scene == self._drawn_scene:  # nothing moved: no new image to draw (a fifth of a second) or estimate
            return
        self._drawn_scene = scene
        image = image_msg(self._draw(*scene))
        image.header.stamp = self.get_clock().now().to_msg()
        image.header.frame_id = self._frame_id
        self._image_pub.publish(image)


def main(args=None):
    sys.exit(run_node(SimCameraNode, "sim_camera", args=args))


if __name__ == "__main__":
    main()

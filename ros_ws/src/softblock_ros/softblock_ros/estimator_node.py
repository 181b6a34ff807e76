"""Estimator node: block angles and assembly mistakes of one chain, seen by a side-view camera.

Subscribes to the silhouette (``camera/silhouette``, sensor_msgs/Image, mono8: a binary silhouette, or
grey with ``threshold``), the current assembly (``assembly/current``, latched) and the measured channel
voltages (``hv/state``). Each image goes to ``estimation.estimate_chain`` with the believed chain ``chain``,
the camera's ``pixel_size_m`` and ``base_pose`` (where the chain's base sits in the image), and the chain's
channel voltage; the result is published as an AssemblyState on ``assembly/estimated`` (the estimated angles
and centerline of the chain that explains the image, in the assembly frame; not the prediction's
``assembly/state``) and as a DiagnosticStatus on ``/diagnostics``: OK "as built", WARN with the mistakes
found, ERROR for an image the chain does not explain or a refused image (the reason named; the node stays up);
a verdict's values name the ``assembly`` it was compared with (the sequencer's ``operator_swap`` step needs it;
a refused image of a known assembly names it too, so a swap step fails on it at once instead of waiting).
With each estimate, the estimated chain's frames, its mount included, go on ``/tf`` under the prefix
``estimated/`` (``softblock_ros.tf_frames``), beside the predicted ones. (Only assembly_state publishes on the latched
``/tf_static``: two latched samples published moments apart could reach a replay's reader as one.)

``estimator/calibrate`` (std_srvs/Trigger): per-block calibration offsets from the last
``calibration_images`` images of the current chain (``estimation.calibrate_chain``); the reply lists them,
and with ``calibration_output`` set they are written there in the format of config/block_calibration.yaml.
"""
from __future__ import annotations

import math
import sys
from collections import deque
from pathlib import Path

import numpy as np
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Image
from softblock_interfaces.msg import Assembly, AssemblyState, ChainState, HvState
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from estimation import ImagePose, calibrate_chain, estimate_chain
from estimation.estimate import Status
from planner.block_calibration import load_block_calibration
from planner.kinematics import chain_blocks, chain_shape
from planner.table import load_table

from .conversions import assembly_from_msg, channel_voltages, mask_from_image, points_msg, safe_voltage
from .parameters import Param, declare
from .qos import LATCHED
from .runner import run_node
from .tf_frames import ESTIMATED_PREFIX, blocks_msg, mounts_msg, stamped

# Best effort matches any camera; depth 1: images that arrive while one is being estimated replace each other.
IMAGE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
LEVELS = {Status.AS_BUILT: DiagnosticStatus.OK, Status.MISTAKES_FOUND: DiagnosticStatus.WARN,
          Status.UNEXPLAINED: DiagnosticStatus.ERROR}
# How the camera sees the chain; the simulated camera (sim_camera_node) takes the same parameters.
VIEW_PARAMETERS = (
    Param("chain", "front_left", "chain of the current assembly the camera sees", kind=str),
    Param("pixel_size_m", 2.5e-4, "size of one pixel in the chain's plane", "m", 1e-6, 0.01),
    Param("base_pose", [0.05, 0.005, math.pi / 2], "the chain base's centre x, y [m] in the image (origin at the "
          "top-left corner, x right, y down) and the direction the chain grows [rad], from image +x toward +y", "",
          -10.0, 10.0, size=3),
    Param("mirrored", False, "the camera looks along the chain's -y: its bending side lies 90 deg counter-clockwise of the growth direction on screen (for the default pose, hanging down, the chain bends to image right)", kind=bool),
)


def camera_view(value: dict) -> tuple[str, float, ImagePose]:
    """(chain name, pixel size [m], base pose in the image) from the declared VIEW_PARAMETERS."""
    return value["chain"], value["pixel_size_m"], ImagePose(*value["base_pose"], mirrored=value["mirrored"])


PARAMETERS = VIEW_PARAMETERS + (
    Param("threshold", -1.0, "grey level above which a pixel is the chain; -1: the image is a binary silhouette",
          "", -1.0, 255.0),
    Param("max_image_pixels", 4_000_000, "larger images are refused before they are decoded", "", 64, 25_000_000,
          kind=int),
    Param("calibration_images", 5, "images the calibration service uses (the last ones of the current chain)", "",
          1, 100, kind=int),
    Param("calibration_output", "", "calibration file the service writes (other blocks' entries kept); empty: the "
          "offsets are only returned", kind=str),
    Param("frame_id", "gripper_base", "frame of the assembly and the estimated centerline", kind=str),
)


class EstimatorNode(Node):
    def __init__(self, **kwargs):
        super().__init__("estimator", **kwargs)
        value = declare(self, PARAMETERS)
        self._chain_name, self._pixel_size, self._pose = camera_view(value)
        self._threshold = None if value["threshold"] < 0 else value["threshold"]
        self._max_pixels, self._frame_id = value["max_image_pixels"], value["frame_id"]
        self._output = value["calibration_output"]
        self._table = load_table()
        self._assembly = None
        self._voltages: dict[str, float] = {}
        self._recent = deque(maxlen=value["calibration_images"])  # (chain, image, voltage) of the current chain

        self._estimate_pub = self.create_publisher(AssemblyState, "assembly/estimated", 10)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._tf_pub = self.create_publisher(TFMessage, "/tf", 10)
        self.create_subscription(Assembly, "assembly/current", self._on_assembly, LATCHED)
        self.create_subscription(HvState, "hv/state", self._on_hv_state, qos_profile_sensor_data)
        self.create_subscription(Image, "camera/silhouette", self._on_image, IMAGE_QOS)
        self.create_service(Trigger, "estimator/calibrate", self._on_calibrate)
        self.get_logger().info(f"estimating chain {self._chain_name!r} at {self._pixel_size * 1e3:g} mm/pixel")

    def _on_assembly(self, message: Assembly) -> None:
        try:
            assembly, _ = assembly_from_msg(message, self._table)
        except ValueError as error:
            self._report(DiagnosticStatus.ERROR, f"assembly refused: {error}")
            return
        self._assembly = assembly
        self._recent.clear()

    def _on_hv_state(self, message: HvState) -> None:
        self._voltages = channel_voltages(message)

    def _believed_chain(self):
        if self._assembly is None:
            raise ValueError("no assembly received on assembly/current yet")
        chain = next((c for c in self._assembly.chains if c.name == self._chain_name), None)
        if chain is None:
            raise ValueError(f"the assembly {self._assembly.name!r} has no chain {self._chain_name!r} "
                             f"(it has {', '.join(c.name for c in self._assembly.chains)})")
        return chain

    def _image_array(self, message: Image) -> np.ndarray:
        pixels = message.height * message.width
        if pixels > self._max_pixels:
            raise ValueError(f"image of {message.width} x {message.height} pixels is larger than max_image_pixels "
                             f"({self._max_pixels})")
        return mask_from_image(message).copy()

    def _on_image(self, message: Image) -> None:
        try:
            chain = self._believed_chain()
            image = self._image_array(message)
            voltage = self._voltages.get(chain.hv_channel, 0.0)
            result = estimate_chain(image, chain, self._pixel_size, self._pose, voltage=voltage, table=self._table,
                                    threshold=self._threshold)
        except ValueError as error:  # on a known assembly a verdict too: what cannot be seen is not verified
            known = [] if self._assembly is None else [KeyValue(key="assembly", value=self._assembly.name)]
            self._report(DiagnosticStatus.ERROR, f"image refused: {error}", known, stamp=message.header.stamp)
            return
        if result.as_built:
            self._recent.append((chain, image, voltage))
        header = Header(stamp=message.header.stamp, frame_id=self._frame_id)
        state, shape = self._estimated(header, result, voltage)
        self._estimate_pub.publish(state)
        mount = mounts_msg([result.chain], self._frame_id, ESTIMATED_PREFIX)
        blocks = blocks_msg({result.chain.name: shape}, ESTIMATED_PREFIX)
        self._tf_pub.publish(stamped(TFMessage(transforms=[*mount.transforms, *blocks.transforms]), header.stamp))
        assembly = KeyValue(key="assembly", value=self._assembly.name)  # what the verdict is on (operator_swap)
        self._report(LEVELS[result.status], result.message, [assembly, *self._values(result)], header.stamp)

    def _estimated(self, header: Header, result, voltage: float) -> tuple[AssemblyState, object]:
        """The estimated chain (the one that explains the image) at its fitted angles, in the assembly frame: the
        AssemblyState and the ``planner.kinematics.ChainShape``."""
        built = result.chain
        _, length, phi, _ = chain_blocks(built, self._table)
        shape = chain_shape(result.theta, length, phi).transformed(
            Rotation.from_quat(built.base_orientation).as_matrix(), built.base_position)
        chain = ChainState(name=built.name, hv_channel=built.hv_channel, voltage=float(voltage),
                           block_angles=[float(a) for a in result.theta], block_valid=[True] * len(result.blocks),
                           centerline=points_msg(shape.points))
        return AssemblyState(header=header, assembly_name=self._assembly.name,
                             safe_voltage=safe_voltage(self._assembly, self._table), chains=[chain]), shape

    @staticmethod
    def _values(result) -> list[KeyValue]:
        values = [KeyValue(key="status", value=result.status.name.lower()),
                  KeyValue(key="residual_m", value=f"{result.residual:.3e}"),
                  KeyValue(key="solve_time_s", value=f"{result.solve_time:.3f}")]
        for mistake in result.mistakes:
            values.append(KeyValue(key="mistake", value=mistake.describe()))
        for number, block in enumerate(result.blocks, start=1):
            values.append(KeyValue(key=f"block {number} design {block.design_id}",
                                   value=f"theta {block.theta:.4f} +- {block.theta_std:.4f} rad, predicted "
                                         f"{block.predicted_theta:.4f} rad, residual {block.residual:.2e} m"))
        return values

    def _report(self, level: bytes, message: str, values=(), stamp=None) -> None:
        if level != DiagnosticStatus.OK:
            self.get_logger().warning(message, throttle_duration_sec=5.0)
        status = DiagnosticStatus(level=level, name=f"estimator: {self._chain_name}", message=message,
                                  hardware_id="camera/silhouette", values=list(values))
        header = Header(stamp=stamp or self.get_clock().now().to_msg())
        self._diagnostics_pub.publish(DiagnosticArray(header=header, status=[status]))

    def _on_calibrate(self, request, response):
        try:
            response.message = self._calibrate()
            response.success = True
        except (ValueError, OSError) as error:
            response.success, response.message = False, f"calibration refused: {error}"
            self.get_logger().warning(response.message)
        return response

    def _calibrate(self) -> str:
        chain = self._believed_chain()
        images = [(image, voltage) for seen, image, voltage in self._recent if seen == chain]
        if len(images) < self._recent.maxlen:
            raise ValueError(f"{len(images)} as-built images of chain {chain.name!r} so far, "
                             f"{self._recent.maxlen} needed (calibration_images)")
        result = calibrate_chain(images, chain, self._pixel_size, self._pose, table=self._table,
                                 threshold=self._threshold)
        if not result.success:
            raise ValueError(result.message)
        offsets = ", ".join(f"{b.serial} {math.degrees(b.offset):+.2f} +- {math.degrees(b.offset_std):.2f} deg"
                            for b in result.blocks)
        text = f"offsets from {len(images)} images: {offsets}"
        if self._output:
            path = Path(self._output)
            document = result.document(load_block_calibration(path))
            path.write_text(yaml.safe_dump(document, sort_keys=False))
            text += f"; written to {path}"
        self.get_logger().info(text)
        return text


def main(args=None):
    sys.exit(run_node(EstimatorNode, "estimator", args=args))


if __name__ == "__main__":
    main()

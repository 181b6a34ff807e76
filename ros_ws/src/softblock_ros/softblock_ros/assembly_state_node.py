"""Assembly-state node: holds the current assembly and publishes its predicted shape at the measured HV.

Latched (transient_local): the assembly on ``assembly/current`` and the lowest safe voltage over its
blocks on ``assembly/safe_voltage`` (the HV driver's ceiling). At ``publish_rate_hz``: the predicted per-block angles
and centerlines at the channel voltages measured on ``hv/state`` (``assembly/state``) and RViz markers
(``assembly/markers``), and each chain's frames on ``/tf`` (the blocks) and ``/tf_static`` (the mounts, latched;
``softblock_ros.tf_frames``). ``assembly/set`` replaces the assembly; an invalid one is refused, the old kept (so
is one with a name, channel, serial or frame longer than MAX_NAME_LENGTH characters).
Block calibration offsets (``block_calibration`` file, by serial) are added to the predicted angles; an
offset a request gives (not 0) wins over the file's for that block.
"""
from __future__ import annotations

import sys

from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from softblock_interfaces.msg import Assembly, AssemblyState, HvState
from softblock_interfaces.srv import SetAssembly
from std_msgs.msg import Float64, Header
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from planner.assembly import load_assembly
from planner.block_calibration import BlockCalibration, load_block_calibration
from planner.kinematics import assembly_centerlines
from planner.table import load_table

from .conversions import (assembly_from_msg, assembly_msg, chain_state_msg, channel_voltages, check_assembly,
                          safe_voltage)
from .markers import assembly_markers
from .parameters import Param, declare
from .paths import resolve_path
from .qos import LATCHED, stream_qos
from .runner import run_node
from .tf_frames import blocks_msg, mounts_msg, stamped

MAX_NAME_LENGTH = 100  # [characters] of each string of an assembly request; the shipped names are below 20


def overlong_string(message: Assembly) -> str:
    """The first string of an assembly request above MAX_NAME_LENGTH characters, as ``field (N characters)``,
    or "". Checked before anything else reads the request, so no error message quotes such a string."""
    fields = [("name", message.name), ("header.frame_id", message.header.frame_id)]
    for c, chain in enumerate(message.chains):
        fields += [(f"chains[{c}].name", chain.name), (f"chains[{c}].hv_channel", chain.hv_channel)]
        fields += [(f"chains[{c}].blocks[{b}].serial", block.serial) for b, block in enumerate(chain.blocks)]
    return next((f"{field} ({len(text)} characters)" for field, text in fields if len(text) > MAX_NAME_LENGTH), "")


PARAMETERS = (
    Param("assembly_file", "assemblies/gripper.yaml", "assembly YAML loaded at start (relative and not found from "
          "the working directory: a shipped file of config/)", kind=str),
    Param("table_path", "", "look-up table file; empty = the planner's default table", kind=str),
    Param("publish_rate_hz", 10.0, "publishing rate of assembly/state and assembly/markers", "Hz", 0.1, 100.0),
    Param("frame_id", "gripper_base", "frame of the assembly, centerlines and markers", kind=str),
    Param("block_calibration", "block_calibration.yaml", "per-block angle offsets by serial (relative and not "
          "found from the working directory: a shipped file of config/); empty = none", kind=str),
)


class AssemblyStateNode(Node):
    def __init__(self, **kwargs):
        super().__init__("assembly_state", **kwargs)
        value = declare(self, PARAMETERS)
        assembly_file, table_path, rate = value["assembly_file"], value["table_path"], value["publish_rate_hz"]
        self._frame_id, calibration_file = value["frame_id"], value["block_calibration"]
        self._table = load_table(resolve_path(table_path)) if table_path else load_table()
        self._block_calibration = self._load_block_calibration(calibration_file)

        self._current_pub = self.create_publisher(Assembly, "assembly/current", LATCHED)
        self._safe_voltage_pub = self.create_publisher(Float64, "assembly/safe_voltage", LATCHED)
        self._state_pub = self.create_publisher(AssemblyState, "assembly/state", stream_qos(rate))
        self._markers_pub = self.create_publisher(MarkerArray, "assembly/markers", stream_qos(rate))
        self._tf_pub = self.create_publisher(TFMessage, "/tf", stream_qos(rate))
        self._tf_static_pub = self.create_publisher(TFMessage, "/tf_static", LATCHED)
        self._voltages: dict[str, float] = {}  # measured channel voltages [V]; absent = not actuated
        self._prediction = None  # (voltages, state, markers, block frames) of the last computation
        assembly = load_assembly(resolve_path(assembly_file))
        check_assembly(assembly, self._table)
        self._use(assembly, self._block_calibration.offsets(assembly))

        # hv/state is read best effort: it matches a reliable or a best-effort publisher.
        self.create_subscription(HvState, "hv/state", self._on_hv_state, qos_profile_sensor_data)
        self.create_service(SetAssembly, "assembly/set", self._on_set)
        self.create_timer(1.0 / rate, self._publish_state)
        self.get_logger().info(f"assembly {assembly.name!r} from {assembly_file}, publishing at {rate} Hz")

    def _load_block_calibration(self, path: str) -> BlockCalibration:
        if not path:
            self.get_logger().warning("block_calibration is empty: predictions use the design angles, no offsets")
            return BlockCalibration(blocks={})
        if not resolve_path(path).is_file():
            raise ValueError(f"block_calibration file {path} not found (empty = no calibration)")
        calibration = load_block_calibration(resolve_path(path))
        self.get_logger().info(f"block calibration: {len(calibration.blocks)} blocks from {path}")
        return calibration

    def _header(self) -> Header:
        return Header(stamp=self.get_clock().now().to_msg(), frame_id=self._frame_id)

    def _use(self, assembly, calibration: dict[str, float]) -> None:
        self._assembly, self._calibration, self._prediction = assembly, calibration, None
        current = assembly_msg(assembly, self._table, calibration)
        current.header = self._header()
        self._current_pub.publish(current)
        self._safe_voltage_pub.publish(Float64(data=safe_voltage(assembly, self._table)))
        self._tf_static_pub.publish(stamped(mounts_msg(assembly.chains, self._frame_id), current.header.stamp))

    def _on_set(self, request, response):
        overlong = overlong_string(request.assembly)
        if overlong:
            response.success = False
            response.message = f"assembly refused: {overlong} is longer than {MAX_NAME_LENGTH} characters"
            self.get_logger().warning(response.message)
            return response
        try:
            assembly, requested = assembly_from_msg(request.assembly, self._table)
            calibration = {**self._block_calibration.offsets(assembly),
                           **{serial: offset for serial, offset in requested.items() if offset}}
        except ValueError as error:
            response.success, response.message = False, f"assembly refused: {error}"
            self.get_logger().warning(response.message)
            return response
        self._use(assembly, calibration)
        response.success, response.message = True, f"assembly {assembly.name!r} with {len(assembly.chains)} chains"
        self.get_logger().info(response.message)
        return response

    def _on_hv_state(self, message: HvState) -> None:
        self._voltages = channel_voltages(message)

    def _predict(self, voltages: dict[str, float]):
        shapes = assembly_centerlines(self._assembly, self._table, voltages, self._calibration)
        state = AssemblyState(assembly_name=self._assembly.name, safe_voltage=safe_voltage(self._assembly, self._table))
        state.chains = [
            chain_state_msg(chain, shapes[chain.name], voltages.get(chain.hv_channel, 0.0))
            for chain in self._assembly.chains
        ]
        markers = assembly_markers(self._assembly, shapes, self._table, Header(frame_id=self._frame_id))
        return voltages, state, markers, blocks_msg(shapes)

    def _publish_state(self) -> None:
        voltages = {ch: self._voltages[ch] for ch in self._assembly.hv_channels if ch in self._voltages}
        if self._prediction is None or self._prediction[0] != voltages:  # recompute only on change
            self._prediction = self._predict(voltages)
        _, state, markers, frames = self._prediction
        state.header = self._header()
        for marker in markers.markers:
            marker.header = state.header
        self._state_pub.publish(state)
        self._markers_pub.publish(markers)
        self._tf_pub.publish(stamped(frames, state.header.stamp))


def main(args=None):
    sys.exit(run_node(AssemblyStateNode, "assembly_state", args=args))


if __name__ == "__main__":
    main()

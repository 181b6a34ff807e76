"""Conversions between the planner's data (assemblies, table rows, shapes, masks, paths) and messages.

No rclpy import: the nodes call these, and so can scripts and tests without ROS running. Messages carry
the full BlockDesign of every block for the reader's convenience, but only the design ID is read back:
the look-up table is the single source of block parameters.
"""
from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import Point, Pose
from sensor_msgs.msg import Image
from softblock_interfaces import msg

from planner.assembly import Assembly, Chain, PlacedBlock
from planner.block_calibration import MAX_OFFSET

BLOCK_DESIGN_FIELDS = (
    "rod_length", "rod_diameter", "prestretch_axial", "prestretch_tangential",
    "theta0", "stiffness", "safe_voltage", "mass",
)
MASK_ENCODINGS = ("mono8", "8UC1")


def block_design_msg(table, design_id: int) -> msg.BlockDesign:
    """The table row of ``design_id`` as a message (KeyError/ValueError from the table if unknown)."""
    row = table.design(int(design_id))
    return msg.BlockDesign(id=int(design_id), **{name: float(getattr(row, name)) for name in BLOCK_DESIGN_FIELDS})


def pose_msg(position, orientation) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position)
    q = pose.orientation
    q.x, q.y, q.z, q.w = (float(v) for v in orientation)
    return pose


def chain_msg(chain: Chain, table, calibration: dict[str, float] | None = None) -> msg.Chain:
    """A chain with the full table row of each block; ``calibration`` maps serial -> angle offset [rad]."""
    calibration = calibration or {}
    return msg.Chain(
        name=chain.name,
        hv_channel=chain.hv_channel,
        base_pose=pose_msg(chain.base_position, chain.base_orientation),
        blocks=[
            msg.PlacedBlock(
                design=block_design_msg(table, block.design_id),
                rotation=block.rotation,
                serial=block.serial,
                calibration_offset=float(calibration.get(block.serial, 0.0)) if block.serial else 0.0,
            )
            for block in chain.blocks
        ],
    )


def designed_chain_msg(name: str, design_ids, table, rotation_steps=None, base_position=(0.0, 0.0, 0.0),
                       base_orientation=(0.0, 0.0, 0.0, 1.0)) -> msg.Chain:
    """A chain message for an optimizer result: blocks by design ID, the given base pose, no HV channel."""
    steps = rotation_steps if rotation_steps is not None else [0] * len(design_ids)
    blocks = tuple(PlacedBlock(int(i), int(k)) for i, k in zip(design_ids, steps, strict=True))
    chain = Chain(name=name, hv_channel="", blocks=blocks, base_position=tuple(base_position),
                  base_orientation=tuple(base_orientation))
    return chain_msg(chain, table)


def assembly_msg(assembly: Assembly, table, calibration: dict[str, float] | None = None) -> msg.Assembly:
    """The assembly as a message; the caller fills the header (stamp, frame_id)."""
    return msg.Assembly(name=assembly.name, chains=[chain_msg(c, table, calibration) for c in assembly.chains])


def check_assembly(assembly: Assembly, table) -> None:
    """ValueError for an assembly without chains or naming the first block whose design ID is unknown."""
    if not assembly.chains:
        raise ValueError(f"assembly {assembly.name!r} has no chains")
    known = {int(i) for i in np.asarray(table.ids)}
    for chain in assembly.chains:
        for b, design_id in enumerate(chain.design_ids):
            if design_id not in known:
                raise ValueError(
                    f"chain {chain.name!r}, block {b}: unknown design ID {design_id} "
                    f"(the table has IDs {min(known)}..{max(known)})"
                )


def check_calibration_offset(block: msg.PlacedBlock) -> None:
    """ValueError unless the block's calibration offset is finite, within the plausible range and, when not
    zero, belongs to a block with a serial (offsets are measured per physical block)."""
    offset = block.calibration_offset
    if not abs(offset) <= MAX_OFFSET:  # also catches NaN
        raise ValueError(f"calibration_offset={offset!r} rad: must be finite and within +-{MAX_OFFSET:.3f} rad")
    if offset and not block.serial:
        raise ValueError(f"calibration_offset={offset!r} rad: needs the block's serial")


def chain_from_msg(chain: msg.Chain) -> Chain:
    """The planner's chain of a message (design IDs, rotations, serials, base pose); ValueError if malformed."""
    blocks = tuple(PlacedBlock(int(block.design.id), PlacedBlock.steps_from_rotation(block.rotation), block.serial)
                   for block in chain.blocks)
    p, q = chain.base_pose.position, chain.base_pose.orientation
    return Chain(chain.name, chain.hv_channel, blocks, (p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


def assembly_from_msg(message: msg.Assembly, table) -> tuple[Assembly, dict[str, float]]:
    """(assembly, calibration serial -> offset [rad]) from a message; ValueError names the bad chain/block."""
    chains, calibration = [], {}
    for c, chain in enumerate(message.chains):
        where = f"chain {chain.name or c!r}"
        for b, block in enumerate(chain.blocks):
            try:
                check_calibration_offset(block)
            except ValueError as error:
                raise ValueError(f"{where}, block {b}: {error}") from None
        try:
            chains.append(chain_from_msg(chain))
        except ValueError as error:
            raise ValueError(f"{where}: {error}") from None
        calibration.update(
            {block.serial: float(block.calibration_offset) for block in chain.blocks if block.serial}
        )
    assembly = Assembly(message.name, tuple(chains))
    check_assembly(assembly, table)
    return assembly, calibration


def safe_voltage(assembly: Assembly, table) -> float:
    """Lowest safe voltage over every block of the assembly [V]."""
    ids = [i for chain in assembly.chains for i in chain.design_ids]
    return float(np.min(np.asarray(table.safe_voltage)[table.index_of(np.array(ids))]))


def channel_voltages(hv_state: msg.HvState) -> dict[str, float]:
    """Channel name -> measured voltage [V] for the prediction: readback noise below 0 V counts as 0 V, and a
    channel without a finite reading is left out (its chains are predicted at rest)."""
    return {c.name: max(c.measured_voltage, 0.0) for c in hv_state.channels if math.isfinite(c.measured_voltage)}


def points_msg(points: np.ndarray) -> list[Point]:
    return [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in points]


def chain_state_msg(chain: Chain, shape, voltage: float) -> msg.ChainState:
    """Predicted state of one chain from its ``planner.kinematics.ChainShape`` at ``voltage`` [V]."""
    return msg.ChainState(
        name=chain.name,
        hv_channel=chain.hv_channel,
        voltage=float(voltage),
        block_angles=[float(a) for a in shape.theta],
        block_valid=[bool(v) for v in shape.valid],
        centerline=points_msg(shape.points),
    )


def mask_from_image(image: Image) -> np.ndarray:
    """(height, width) uint8 array of a mono8 image message; ValueError for another encoding or bad size."""
    if image.encoding not in MASK_ENCODINGS:
        raise ValueError(f"image encoding must be mono8, got {image.encoding!r}")
    height, width, step = image.height, image.width, image.step
    if step < width or len(image.data) != height * step:
        raise ValueError(
            f"image data has {len(image.data)} bytes, expected height {height} x step {step} (width {width})"
        )
    rows = np.frombuffer(bytes(image.data), dtype=np.uint8).reshape(height, step)
    return rows[:, :width]


def image_msg(mask: np.ndarray) -> Image:
    """A mono8 image message of a 2D uint8 array (e.g. to send an object mask to the planner)."""
    mask = np.ascontiguousarray(mask, dtype=np.uint8)
    if mask.ndim != 2:
        raise ValueError(f"mask must be a 2D array, got shape {mask.shape}")
    height, width = mask.shape
    return Image(height=height, width=width, encoding="mono8", step=width, data=mask.tobytes())


def path_from_points(points) -> np.ndarray:
    """(n, 3) array of geometry_msgs/Point; ValueError names the first non-finite point."""
    path = np.array([[p.x, p.y, p.z] for p in points], dtype=float).reshape(-1, 3)
    bad = np.flatnonzero(~np.all(np.isfinite(path), axis=1))
    if bad.size:
        raise ValueError(f"path point {bad[0]} is not finite: {path[bad[0]].tolist()}")
    return path


def inventory_from_lists(ids, counts) -> dict[int, int] | None:
    """Inventory design ID -> count from the request's parallel lists; None when both are empty."""
    if len(ids) != len(counts):
        raise ValueError(f"inventory_ids has {len(ids)} entries but inventory_counts has {len(counts)}")
    if not len(ids):
        return None
    inventory: dict[int, int] = {}
    for design_id, count in zip(ids, counts):
        inventory[int(design_id)] = inventory.get(int(design_id), 0) + int(count)
    return inventory

"""TF of an assembly's chains (``/tf``, ``/tf_static``): fixed mounts and the blocks' frames. No rclpy import.

Frames of chain C (``prefix`` in front of each, e.g. ``estimated/`` for the shape seen by the camera):

- ``C/base``: the chain's mount in the assembly frame (``frame_id``, e.g. ``gripper_base``); fixed, on /tf_static;
- ``C/block_k``: the end of block k (1 = at the base), a child of ``C/block_(k-1)`` (block 1 of ``C/base``);
  it moves with the voltage, on /tf.

The frames are those of ``planner.kinematics`` (a chain grows along its frames' +z, bending toward +x).
"""
from __future__ import annotations

from collections.abc import Iterable

from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Vector3
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from planner.frames import link_transforms, quaternions

ESTIMATED_PREFIX = "estimated/"  # the frames of the estimated shape (assembly/estimated)


def chain_frame(chain: str, index: int, prefix: str = "") -> str:
    """The frame of chain ``chain`` at ``index``: 0 its base, k the end of block k."""
    return f"{prefix}{chain}/base" if index == 0 else f"{prefix}{chain}/block_{index}"


def _transform(parent: str, child: str, rotation_xyzw, translation) -> TransformStamped:
    x, y, z, w = (float(v) for v in rotation_xyzw)
    tx, ty, tz = (float(v) for v in translation)
    return TransformStamped(header=Header(frame_id=parent), child_frame_id=child,
                            transform=Transform(translation=Vector3(x=tx, y=ty, z=tz),
                                                rotation=Quaternion(x=x, y=y, z=z, w=w)))


def mounts_msg(chains: Iterable, frame_id: str, prefix: str = "") -> TFMessage:
    """The fixed mount of each ``planner.assembly.Chain`` (its base pose) in the assembly frame ``frame_id``."""
    return TFMessage(transforms=[_transform(frame_id, chain_frame(chain.name, 0, prefix), chain.base_orientation,
                                            chain.base_position) for chain in chains])


def blocks_msg(shapes: dict, prefix: str = "") -> TFMessage:
    """Each block end in the frame before it, for ``shapes`` (chain name -> ``planner.kinematics.ChainShape``)."""
    transforms = []
    for name, shape in shapes.items():
        rotations, translations = link_transforms(shape.rotations, shape.positions)
        transforms += [_transform(chain_frame(name, k, prefix), chain_frame(name, k + 1, prefix), rotation, translation)
                       for k, (rotation, translation) in enumerate(zip(quaternions(rotations), translations))]
    return TFMessage(transforms=transforms)


def stamped(message: TFMessage, stamp) -> TFMessage:
    """``message`` with every transform stamped ``stamp`` (builtin_interfaces/Time); returns it."""
    for transform in message.transforms:
        transform.header.stamp = stamp
    return message

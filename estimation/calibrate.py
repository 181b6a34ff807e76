"""Per-block calibration offsets from images of a chain at rest and actuated (paper, Experimental Section).

The paper measures each block's "calibration angle" and adds it to the model's angle at every voltage.
Here the angle comes from images: every image (one voltage each) is estimated with ``estimate_chain``
and each block's offset is estimated angle - table angle at that voltage; the offsets of all images are
combined by their inverse variances. The result is written in the format of config/block_calibration.yaml
(block serial -> design ID, offset_rad). A chain that is not as built is refused: its offsets would
describe the wrong blocks.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimation.estimate import ChainEstimate, estimate_chain
from estimation.view import ImagePose
from planner.assembly import Chain
from planner.block_calibration import MAX_OFFSET, BlockCalibration, parse_block_calibration
from planner.table import load_table

INCONSISTENT = 3.0  # Birge ratio above which a block's offsets disagree between images


@dataclass(frozen=True)
class CalibrationImage:
    image: object  # path or 2D array
    voltage: float  # on the chain's channel [V]


@dataclass(frozen=True)
class BlockOffsetEstimate:
    serial: str
    design_id: int
    offset: float  # [rad] added to the design's table angle
    offset_std: float  # [rad]
    per_image: tuple[float, ...]  # offset seen in each image [rad]
    consistent: bool  # the images agree within their uncertainties (Birge ratio <= INCONSISTENT)


@dataclass(frozen=True)
class CalibrationResult:
    success: bool  # every block's offsets agree between the images
    message: str
    blocks: tuple[BlockOffsetEstimate, ...]
    estimates: tuple[ChainEstimate, ...]

    def document(self, existing: BlockCalibration | None = None) -> dict:
        """The calibration file's structure: ``existing`` entries kept, this chain's blocks replaced."""
        entries = {} if existing is None else {
            serial: {"design_id": entry.design_id, "offset_rad": entry.offset} for serial, entry in existing.blocks.items()
        }
        for block in self.blocks:
            entries[block.serial] = {"design_id": block.design_id, "offset_rad": round(block.offset, 6)}
        document = {"blocks": dict(sorted(entries.items()))}
        parse_block_calibration(document, "new calibration")  # the file must load again
        return document


def _check_chain(chain: Chain) -> None:
    missing = [i + 1 for i, block in enumerate(chain.blocks) if not block.serial]
    if missing:
        raise ValueError(f"chain {chain.name!r}: blocks {missing} have no serial; a calibration is stored per block serial")
    serials = [block.serial for block in chain.blocks]
    repeated = sorted({s for s in serials if serials.count(s) > 1})
    if repeated:
        raise ValueError(f"chain {chain.name!r}: serials {repeated} appear more than once")


def calibrate_chain(images: Sequence, chain: Chain, pixel_size: float, pose: ImagePose, *, table=None,
                    threshold: float | None = None, calibration=None, options=None) -> CalibrationResult:
    """Offsets of every block of ``chain`` from ``images`` (``CalibrationImage`` or (image, voltage) pairs).

    ``calibration`` (the current offsets, as for ``estimate_chain``) only sets what the images are judged
    against; the offsets found are always relative to the table.

    ValueError for no images, blocks without (or with repeated) serials, a bad image, an image in which the
    chain is not as built (the message names the image and the mistakes), or an offset beyond the
    calibration file's limit.
    """
    images = [item if isinstance(item, CalibrationImage) else CalibrationImage(*item) for item in images]
    if not images:
        raise ValueError("calibration needs at least one image")
    _check_chain(chain)
    table = load_table() if table is None else table
    estimates = []
    for number, item in enumerate(images, start=1):
        try:
            result = estimate_chain(item.image, chain, pixel_size, pose, voltage=item.voltage, table=table,
                                    threshold=threshold, calibration=calibration, options=options)
        except ValueError as error:
            raise ValueError(f"image {number} ({item.voltage:g} V): {error}") from None
        if not result.as_built:
            raise ValueError(f"image {number} ({item.voltage:g} V): {result.message}; fix the assembly (or the "
                             "assembly file) before calibrating")
        estimates.append(result)
    table_angles = np.array([table.angle_at(chain.design_ids, item.voltage)[0] for item in images])
    offsets = np.array([e.theta for e in estimates]) - table_angles  # (images, blocks)
    spread = np.array([[b.theta_std for b in e.blocks] for e in estimates])
    weights = 1.0 / np.maximum(spread, 1e-6) ** 2
    mean = np.sum(weights * offsets, axis=0) / np.sum(weights, axis=0)
    formal = 1.0 / np.sqrt(np.sum(weights, axis=0))
    count = len(estimates)
    birge = np.sqrt(np.sum(weights * (offsets - mean) ** 2, axis=0) / (count - 1)) if count > 1 else np.ones_like(mean)
    blocks, notes = [], []
    for k, block in enumerate(chain.blocks):
        if abs(mean[k]) > MAX_OFFSET:
            raise ValueError(f"block {k + 1} ({block.serial}): offset {math.degrees(mean[k]):.1f} deg is beyond "
                             f"+-{math.degrees(MAX_OFFSET):.0f} deg; is it really design {block.design_id}?")
        consistent = bool(birge[k] <= INCONSISTENT)
        if not consistent:
            seen = ", ".join(f"{math.degrees(o):.2f}" for o in offsets[:, k])
            notes.append(f"block {k + 1} ({block.serial}) offsets differ between images ({seen} deg): "
                         "its stroke differs from the table's")
        blocks.append(BlockOffsetEstimate(
            serial=block.serial, design_id=block.design_id, offset=float(mean[k]),
            offset_std=float(formal[k] * max(1.0, birge[k])), per_image=tuple(float(o) for o in offsets[:, k]),
            consistent=consistent,
        ))
    message = f"calibrated {len(blocks)} blocks from {count} images"
    if notes:
        message += "; " + "; ".join(notes)
    return CalibrationResult(success=not notes, message=message, blocks=tuple(blocks), estimates=tuple(estimates))

"""Per-block angle offsets: each physical block (by serial) may deviate from its design's angle.

The paper measures every block's bending angle with the rods fitted but before the membrane
goes on (ideally 0; in practice within +-2.5 deg) and adds it to the model angle. The offsets
live in config/block_calibration.yaml::

    blocks:
      SB-0001: {design_id: 15, offset_rad: 0.012}
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from softblock_config import config_file

from planner.bounded_yaml import load_yaml_file
from planner.table import design_indices

DEFAULT_CALIBRATION_PATH = config_file("block_calibration.yaml")
MAX_OFFSET = math.radians(10.0)  # larger than any plausible manufacturing error: a typo or degrees


@dataclass(frozen=True)
class BlockOffset:
    design_id: int
    offset: float  # added to the design's bending angle [rad]


@dataclass(frozen=True)
class BlockCalibration:
    blocks: dict  # serial -> BlockOffset

    def offset_for(self, serial: str, design_id: int) -> float:
        """Offset [rad] of a placed block; 0 for blocks without a serial or calibration entry.

        ValueError if the serial is calibrated as a different design (a block placed wrongly).
        """
        entry = self.blocks.get(serial) if serial else None
        if entry is None:
            return 0.0
        if entry.design_id != design_id:
            raise ValueError(f"block {serial!r} is calibrated as design {entry.design_id}, not {design_id}")
        return entry.offset

    def offsets(self, assembly) -> dict[str, float]:
        """Serial -> offset [rad] of the calibrated blocks of ``assembly`` (a ``planner.assembly.Assembly``);
        ValueError naming the chain and block placed as another design than it is calibrated as."""
        offsets = {}
        for chain in assembly.chains:
            for b, block in enumerate(chain.blocks):
                try:
                    offset = self.offset_for(block.serial, block.design_id)
                except ValueError as error:
                    raise ValueError(f"chain {chain.name!r}, block {b}: {error}") from None
                if block.serial in self.blocks:
                    offsets[block.serial] = offset
        return offsets


def parse_block_calibration(document, source: str = "block calibration") -> BlockCalibration:
    if document is None:
        return BlockCalibration(blocks={})
    if not isinstance(document, dict) or not isinstance(document.get("blocks", {}), dict):
        raise ValueError(f"{source}: expected a mapping with a 'blocks' mapping of serial -> entry")
    blocks = {}
    for serial, entry in (document.get("blocks") or {}).items():
        if not isinstance(entry, dict) or set(entry) != {"design_id", "offset_rad"}:
            raise ValueError(f"{source}: block {serial!r} needs exactly design_id and offset_rad")
        try:
            design_indices(entry["design_id"])
        except ValueError as error:
            raise ValueError(f"{source}: block {serial!r}: {error}") from None
        offset = entry["offset_rad"]
        if isinstance(offset, bool) or not isinstance(offset, (int, float)) or not abs(offset) <= MAX_OFFSET:
            raise ValueError(
                f"{source}: block {serial!r}: offset_rad must be a number within +-{MAX_OFFSET:.3f} rad, got {offset!r}"
            )
        blocks[str(serial)] = BlockOffset(design_id=int(entry["design_id"]), offset=float(offset))
    return BlockCalibration(blocks=blocks)


def load_block_calibration(path=DEFAULT_CALIBRATION_PATH) -> BlockCalibration:
    """Read the per-block offsets; a missing file means no block is calibrated."""
    path = Path(path)
    if not path.is_file():
        return BlockCalibration(blocks={})
    return parse_block_calibration(load_yaml_file(path), str(path))

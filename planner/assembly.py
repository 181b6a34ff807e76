"""Assemblies: named chains of building blocks, each chain wired to one HV channel.

A block is placed by its look-up-table design ID and by which of the 12 snap-fits it uses:
``rotation_steps`` k rotates it by k * 30 degrees about its local z axis relative to the block before
it. Assemblies are read from and written to YAML (``config/assemblies/*.yaml``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from .bounded_yaml import YAMLInputError, load_yaml_file

SNAP_FITS = 12
ROTATION_STEP = 2.0 * math.pi / SNAP_FITS  # 30 degrees [rad]


@dataclass(frozen=True)
class PlacedBlock:
    design_id: int
    rotation_steps: int = 0  # snap-fit index 0..11, relative to the previous block
    serial: str = ""  # physical block serial, for its calibration offset

    def __post_init__(self) -> None:
        # bool is an int subclass, but `id: true` is a typo, not design 1
        if isinstance(self.design_id, bool) or not isinstance(self.design_id, int) or self.design_id < 1:
            raise ValueError(f"design_id must be a positive integer, got {self.design_id!r}")
        if (isinstance(self.rotation_steps, bool) or not isinstance(self.rotation_steps, int)
                or not 0 <= self.rotation_steps < SNAP_FITS):
            raise ValueError(
                f"rotation_steps must be an integer 0..{SNAP_FITS - 1}, got {self.rotation_steps!r}"
            )

    @property
    def rotation(self) -> float:
        """Rotation about the local z axis relative to the previous block [rad]."""
        return self.rotation_steps * ROTATION_STEP

    @staticmethod
    def steps_from_rotation(rotation: float) -> int:
        """Snap-fit index for a rotation in rad; ValueError unless it is a multiple of 30 degrees."""
        steps = rotation / ROTATION_STEP
        nearest = round(steps) if math.isfinite(steps) else None  # round(nan) would raise its own error
        if nearest is None or abs(steps - nearest) > 1e-6:
            raise ValueError(f"rotation {rotation!r} rad is not a multiple of 30 degrees")
        return nearest % SNAP_FITS


@dataclass(frozen=True)
class Chain:
    name: str
    hv_channel: str
    blocks: tuple[PlacedBlock, ...]
    base_position: tuple[float, float, float] = (0.0, 0.0, 0.0)  # [m] in the assembly frame
    base_orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)  # quaternion x, y, z, w

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("chain name must not be empty")
        if not self.blocks:
            raise ValueError(f"chain {self.name!r} has no blocks")
        if len(self.base_position) != 3 or not all(map(math.isfinite, self.base_position)):
            raise ValueError(f"chain {self.name!r}: base_position must be 3 finite numbers [m]")
        norm = math.sqrt(sum(q * q for q in self.base_orientation))
        if len(self.base_orientation) != 4 or not abs(norm - 1.0) < 1e-6:
            raise ValueError(f"chain {self.name!r}: base_orientation must be a unit quaternion (x, y, z, w)")

    @property
    def design_ids(self) -> tuple[int, ...]:
        return tuple(block.design_id for block in self.blocks)


@dataclass(frozen=True)
class Assembly:
    name: str
    chains: tuple[Chain, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        names = [chain.name for chain in self.chains]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(f"assembly {self.name!r}: duplicate chain names {duplicates}")

    def chain(self, name: str) -> Chain:
        for chain in self.chains:
            if chain.name == name:
                return chain
        raise KeyError(f"assembly {self.name!r} has no chain {name!r}")

    @property
    def hv_channels(self) -> tuple[str, ...]:
        """HV channel names in order of first use."""
        return tuple(dict.fromkeys(chain.hv_channel for chain in self.chains))

    def with_chains(self, *chains: Chain) -> Assembly:
        """A copy where chains of the same name are replaced and new ones appended."""
        replaced = {chain.name: chain for chain in chains}
        kept = tuple(replaced.pop(c.name, c) for c in self.chains)
        return Assembly(self.name, kept + tuple(replaced.values()))


ASSEMBLY_KEYS = {"name", "chains"}
CHAIN_KEYS = {"name", "hv_channel", "blocks", "base_position", "base_orientation"}
BLOCK_KEYS = {"id", "rotation_steps", "serial"}


def _check_keys(where: str, data, allowed: set[str]) -> None:
    """ValueError unless ``data`` is a mapping whose keys are all in ``allowed`` (a misspelt key is not
    silently ignored)."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a mapping with keys {sorted(allowed)}, got {type(data).__name__}")
    unknown = sorted(str(key) for key in set(data) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def assembly_from_dict(data: dict) -> Assembly:
    """Build an assembly from its YAML structure; errors name the offending chain, block or key."""
    if not isinstance(data, dict) or "name" not in data or "chains" not in data:
        raise ValueError("an assembly needs the keys 'name' and 'chains'")
    _check_keys("assembly", data, ASSEMBLY_KEYS)
    if not isinstance(data["chains"], list):
        raise ValueError("assembly: 'chains' must be a list of chains")
    chains = []
    for i, chain in enumerate(data["chains"]):
        where = f"chain {chain.get('name', i) if isinstance(chain, dict) else i!r}"
        try:
            _check_keys(where, chain, CHAIN_KEYS)
            if not isinstance(chain.get("blocks"), list):
                raise ValueError("'blocks' must be a list of blocks")
            for b, block in enumerate(chain["blocks"]):
                _check_keys(f"block {b}", block, BLOCK_KEYS)
            blocks = tuple(
                PlacedBlock(
                    design_id=block["id"],
                    rotation_steps=block.get("rotation_steps", 0),
                    serial=str(block.get("serial", "")),
                )
                for block in chain["blocks"]
            )
            chains.append(
                Chain(
                    name=chain["name"],
                    hv_channel=chain["hv_channel"],
                    blocks=blocks,
                    base_position=tuple(float(v) for v in chain.get("base_position", (0, 0, 0))),
                    base_orientation=tuple(
                        float(v) for v in chain.get("base_orientation", (0, 0, 0, 1))
                    ),
                )
            )
        except KeyError as missing:
            raise ValueError(f"{where}: missing key {missing}") from None
        except (TypeError, ValueError) as error:
            raise ValueError(f"{where}: {error}") from None
    return Assembly(name=str(data["name"]), chains=tuple(chains))


def assembly_to_dict(assembly: Assembly) -> dict:
    return {
        "name": assembly.name,
        "chains": [
            {
                "name": chain.name,
                "hv_channel": chain.hv_channel,
                "base_position": list(chain.base_position),
                "base_orientation": list(chain.base_orientation),
                "blocks": [
                    {"id": b.design_id, "rotation_steps": b.rotation_steps}
                    | ({"serial": b.serial} if b.serial else {})
                    for b in chain.blocks
                ],
            }
            for chain in assembly.chains
        ],
    }


def load_assembly(path: str | Path) -> Assembly:
    path = Path(path)
    try:
        data = load_yaml_file(path)
    except YAMLInputError as error:
        raise ValueError(f"cannot read assembly file {error}") from None
    try:
        return assembly_from_dict(data)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


def save_assembly(assembly: Assembly, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(assembly_to_dict(assembly), sort_keys=False))

"""Mass estimate of a block: rigid parts plus the NiTi rods and the membrane actually used.

The paper gives only 0.9-1.1 g for L = 10-15 mm. The rods and membrane are computed from their
volumes; the printed caps with terminals (fixed) and the protective sheets plus electrodes (per
unit free length) are two constants fitted to those two figures by planner.model_calibration.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.block_model import BlockDesigns

NITI_DENSITY = 6450.0  # [kg/m^3]


@dataclass(frozen=True)
class MassConstants:
    fixed: float  # two caps, snap-fits and terminals [kg]
    per_length: float  # protective sheets and electrodes per metre of free length [kg/m]


# Output of `python -m planner calibrate` (planner/model_calibration.py).
CALIBRATED_MASS = MassConstants(fixed=4.8409e-04, per_length=3.5092e-02)


def component_mass(designs: BlockDesigns) -> np.ndarray:
    """Mass of the two NiTi rods and the active membrane [kg] (the parts that vary by design)."""
    # Each rod also runs through both caps, where it is glued in.
    rod_length = designs.rod_length + 2.0 * designs.geometry.cap_length
    rods = 2.0 * NITI_DENSITY * math.pi * designs.rod_diameter**2 / 4.0 * rod_length
    arc = designs.membrane.length
    # Film volume is conserved: its current thickness times area equals t0 times reference area.
    film = designs.material.density * designs.film_thickness * arc * designs.rod_length / (
        designs.prestretch_axial * designs.prestretch_tangential
    )
    return rods + film


def estimate_mass(designs: BlockDesigns, constants: MassConstants = CALIBRATED_MASS) -> np.ndarray:
    """Estimated block mass [kg]."""
    return constants.fixed + constants.per_length * designs.rod_length + component_mass(designs)

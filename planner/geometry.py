"""Fixed block geometry and the paper's 84-design grid (section 2.2.1)."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class BlockGeometry:
    outer_diameter: float = 25e-3  # linking-cap diameter [m]
    rod_depth: float = 8e-3  # h: from the top of the cap circle down to the NiTi rods [m]
    cap_length: float = 2.5e-3  # axial length of one linking cap [m]

    def __post_init__(self) -> None:
        if not self.outer_diameter > 0.0:
            raise ValueError(f"outer_diameter must be positive, got {self.outer_diameter!r}")
        if not 0.0 < self.rod_depth < self.outer_diameter:
            raise ValueError(f"rod_depth must lie inside the cap circle, got {self.rod_depth!r}")
        if not self.cap_length >= 0.0:
            raise ValueError(f"cap_length must be non-negative, got {self.cap_length!r}")

    @property
    def radius(self) -> float:
        return 0.5 * self.outer_diameter

    @property
    def rod_height(self) -> float:
        """Height of the rods' bending axis above the cap centre [m] (R - h)."""
        return self.radius - self.rod_depth


PAPER_GEOMETRY = BlockGeometry()

# The full-factorial design grid; design IDs run lambda_1 fastest, then L, then D.
PRESTRETCH_AXIAL_VALUES = (1.5, 1.6, 1.7, 1.8, 1.9, 2.0, 2.1)
ROD_LENGTH_VALUES = (10e-3, 12.5e-3, 15e-3)  # [m]
ROD_DIAMETER_VALUES = (0.31e-3, 0.44e-3, 0.62e-3, 0.763e-3)  # [m]
AREAL_PRESTRETCH = 2.5  # lambda_1 * lambda_2 for every design (equal film thickness)
DESIGN_COUNT = len(PRESTRETCH_AXIAL_VALUES) * len(ROD_LENGTH_VALUES) * len(ROD_DIAMETER_VALUES)

"""Dielectric-elastomer film materials: Ogden hyperelastic constants plus electrical properties.

Ogden convention (the paper's eqs 4-8 and Abaqus): W = sum_i 2 mu_i / alpha_i**2
(l1**a_i + l2**a_i + l3**a_i - 3), so the small-strain shear modulus is sum(mu_i).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

VACUUM_PERMITTIVITY = 8.8541878128e-12  # [F/m]


@dataclass(frozen=True)
class OgdenMaterial:
    name: str
    mu: tuple[float, ...]  # Ogden moduli [Pa]
    alpha: tuple[float, ...]  # Ogden exponents [-]
    relative_permittivity: float  # [-]
    breakdown_field: float  # dielectric strength [V/m]
    nominal_thickness: float  # unstretched film thickness as sold [m]
    density: float  # [kg/m^3]

    def __post_init__(self) -> None:
        if len(self.mu) != len(self.alpha) or not self.mu:
            raise ValueError(f"{self.name}: mu and alpha must be non-empty and of equal length")
        if not all(np.isfinite(self.mu)) or not all(np.isfinite(self.alpha)):
            raise ValueError(f"{self.name}: mu and alpha must be finite")
        if any(a == 0.0 for a in self.alpha):
            raise ValueError(f"{self.name}: alpha must be non-zero")
        for label, value in (
            ("relative_permittivity", self.relative_permittivity),
            ("breakdown_field", self.breakdown_field),
            ("nominal_thickness", self.nominal_thickness),
            ("density", self.density),
        ):
            if not value > 0.0:
                raise ValueError(f"{self.name}: {label} must be positive, got {value!r}")

    @property
    def permittivity(self) -> float:
        """Absolute permittivity eps0 * eps_r [F/m]."""
        return VACUUM_PERMITTIVITY * self.relative_permittivity


# The paper's 3-term fit (section 4) of its own uniaxial + pure-shear tests. Relative permittivity
# 2.8 and dielectric strength 100 V/um are Wacker's data-sheet values for ELASTOSIL Film 2030
# (80 V/um would put the breakdown of the calibrated ID 15 film below the 2.4-2.5 kV the paper
# actually applies to it).
ELASTOSIL_2030 = OgdenMaterial(
    name="ELASTOSIL 2030",
    mu=(0.096815e6, 0.14973e6, 0.011493e6),
    alpha=(2.8639, 3.23882, 4.450305),
    relative_permittivity=2.8,
    breakdown_field=100e6,
    nominal_thickness=100e-6,
    density=1100.0,
)

# 3M VHB 4910 acrylic tape (1 mm). Hyperelasticity as the neo-Hookean special case of Ogden
# (alpha = 2) with the shear modulus 45 kPa that Koh, Suo and co-workers use for VHB 4910;
# eps_r = 4.7 (Kofod et al.). Dielectric strength rises steeply with prestretch (Kofod et al.
# report about 20 to 218 V/um); 60 V/um is a conservative value for the ~2.5x areal prestretch here.
VHB_4910 = OgdenMaterial(
    name="VHB 4910",
    mu=(45e3,),
    alpha=(2.0,),
    relative_permittivity=4.7,
    breakdown_field=60e6,
    nominal_thickness=1.0e-3,
    density=960.0,
)

MATERIALS = {"elastosil": ELASTOSIL_2030, "vhb4910": VHB_4910}


def material_by_name(name: str) -> OgdenMaterial:
    """Look a material up by key ('elastosil', 'vhb4910'); ValueError listing the known keys."""
    try:
        return MATERIALS[name.lower()]
    except KeyError:
        raise ValueError(f"material {name!r} unknown; choose one of {sorted(MATERIALS)}") from None

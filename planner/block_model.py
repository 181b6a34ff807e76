"""Reduced-order physics of one building block: prestretched DEA membrane against two NiTi rods.

Model (assumptions written out in docs/block_model.md):

* The two rods bend with constant curvature (the paper's kinematics), so one angle theta
  describes the block. Their bending axis lies ``rod_depth`` (h) below the top of the cap circle.
* Where the active membrane lies on the cap outline is the model's ``MembraneLayout``:
  ``beyond_rods`` (shipped) covers the outline on the far side of the rods, from one rod to the
  other, so its arc is set by h alone and the block bends away from the rods; ``top_arc`` covers a
  fitted arc centred on the cap top and bends toward it; ``full_wrap`` covers the whole outline.
  The membrane is cut into N axial strips; a strip at height d above the rod axis (measured toward
  the side the block bends to) runs between the caps. Its reference length is L / lambda_1 and its
  hoop stretch stays lambda_2 (held by the rigid caps), so bending changes only its axial stretch.
* Rods (``RodLaw``): ``constant_curvature`` resists with M = 2 E I theta / L, I = pi D^4 / 64 (exact
  for rods clamped in the caps under end moments); ``beam_column`` adds the membrane's axial
  compression of the rods (end rotation M L / EI * tan(u) / u, u = (L / 2) sqrt(P / EI)).
* Fibre length l(theta): ``"arc"`` keeps the fibre parallel to the rods (l = L - d theta, the
  paper's constant-curvature picture); ``"chord"`` uses the straight line between the two
  anchor points on the rotated caps (l = (L - d theta) sin(theta/2) / (theta/2)), exact for the
  constant-curvature rods. ``"closed_form"`` linearises the arc model about theta = 0.
* Strip stress: plane-stress incompressible Ogden, minus the Maxwell stress eps (V/t)^2 at the
  strip's current thickness t = t0 / (lambda_a lambda_2). A strip cannot carry compression
  (it wrinkles), so its force is w t max(sigma, 0).
* Equilibrium by virtual work: sum_k f_k (-dl_k/dtheta) = rod moment.

An equilibrium is only reported as valid if some strip still holds tension, the tangent stiffness is
positive (no electromechanical pull-in), the caps do not touch and the field stays below the
material's dielectric strength; otherwise the angle is NaN and the status says which limit was crossed.
"""
from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import elementwise

from planner.geometry import AREAL_PRESTRETCH, PAPER_GEOMETRY, BlockGeometry
from planner.materials import ELASTOSIL_2030, VACUUM_PERMITTIVITY, OgdenMaterial
from planner.ogden import biaxial_cauchy_stress, biaxial_cauchy_stress_slope


class MembraneLayout(str, enum.Enum):
    """Which part of the cap outline the active membrane covers."""

    BEYOND_RODS = "beyond_rods"  # from rod to rod around the far side of the cap: the arc follows from h
    TOP_ARC = "top_arc"  # an arc centred on the cap top, its half angle fitted
    FULL_WRAP = "full_wrap"  # the whole outline


class RodLaw(str, enum.Enum):
    """How the two rods resist the membrane."""

    CONSTANT_CURVATURE = "constant_curvature"  # end moments only: M = 2 E I theta / L
    BEAM_COLUMN = "beam_column"  # end moments plus the membrane's axial compression


@dataclass(frozen=True)
class Mechanics:
    """The physics a model uses; benchmarks/block_model_loo.py compares the alternatives."""

    membrane: MembraneLayout = MembraneLayout.BEYOND_RODS
    rods: RodLaw = RodLaw.CONSTANT_CURVATURE

    def __post_init__(self) -> None:
        object.__setattr__(self, "membrane", MembraneLayout(self.membrane))
        object.__setattr__(self, "rods", RodLaw(self.rods))

    @property
    def label(self) -> str:
        return f"{self.membrane.value}, {self.rods.value}"


@dataclass(frozen=True)
class ModelConstants:
    """Constants the paper does not give; fitted by planner.model_calibration to its published points."""

    film_thickness: float  # effective unstretched film thickness t0 [m]
    rod_modulus: float  # NiTi Young's modulus [Pa]
    mechanics: Mechanics = Mechanics()
    # Only the TOP_ARC layout has one: the active membrane covers |psi| <= this, psi from the cap top [rad].
    membrane_half_angle: float | None = None

    def __post_init__(self) -> None:
        fitted_arc = self.mechanics.membrane == MembraneLayout.TOP_ARC
        if fitted_arc and not (self.membrane_half_angle is not None and 0.0 < self.membrane_half_angle <= math.pi):
            raise ValueError(f"the top_arc layout needs membrane_half_angle in (0, pi], got {self.membrane_half_angle!r}")
        if not fitted_arc and self.membrane_half_angle is not None:
            raise ValueError(f"membrane_half_angle belongs to the top_arc layout only, not {self.mechanics.membrane.value}")


# Output of `python -m planner calibrate` (planner/model_calibration.py); a test re-runs the fit.
CALIBRATED_CONSTANTS = ModelConstants(film_thickness=8.0917e-05, rod_modulus=3.6539e10)


@dataclass(frozen=True)
class MembraneArc:
    """The active membrane's arc of the cap outline, seen from the side the block bends to.

    psi runs around the outline from its point farthest toward the bend; the membrane covers
    |psi| <= half_angle. A point at psi lies d = centre_offset + R cos(psi) above the rod axis.
    """

    half_angle: float  # [rad]
    centre_offset: float  # cap centre's height above the rod axis, toward the bend [m]
    radius: float  # [m]

    @classmethod
    def of(cls, constants: ModelConstants, geometry: BlockGeometry) -> "MembraneArc":
        layout, r, y = constants.mechanics.membrane, geometry.radius, geometry.rod_height
        if layout == MembraneLayout.TOP_ARC:
            return cls(constants.membrane_half_angle, -y, r)
        # Bending away from the rods, the cap centre lies y beyond them; the membrane ends at the rods.
        half_angle = math.pi if layout == MembraneLayout.FULL_WRAP else math.acos(-y / r)
        return cls(half_angle, y, r)

    @property
    def length(self) -> float:
        """Arc length of the membrane on the cap outline [m]."""
        return 2.0 * self.half_angle * self.radius

    @property
    def reach(self) -> float:
        """Distance from the rod axis to the outline's farthest point toward the bend [m]."""
        return self.centre_offset + self.radius

    def strips(self, n_strips: int) -> tuple[np.ndarray, float]:
        """Heights d of the strip mid-lines above the rod axis [m] and each strip's width [m]."""
        edges = np.linspace(-self.half_angle, self.half_angle, n_strips + 1)
        mid = 0.5 * (edges[1:] + edges[:-1])
        return self.centre_offset + self.radius * np.cos(mid), self.radius * (edges[1] - edges[0])

    def moments(self) -> tuple[float, float]:
        """First and second moments of the arc about the rod axis: int d ds, int d^2 ds."""
        r, c, b = self.radius, self.centre_offset, self.half_angle
        first = 2.0 * r * (r * math.sin(b) + c * b)
        second = r * (r * r * (b + math.sin(b) * math.cos(b)) + 4.0 * r * c * math.sin(b) + 2.0 * c * c * b)
        return first, second


class Status(enum.IntEnum):
    OK = 0
    MEMBRANE_SLACK = 1  # no strip holds tension any more: the membrane no longer holds the block's shape
    PULL_IN = 2  # tangent stiffness <= 0: electromechanical instability
    BREAKDOWN = 3  # field above the film's dielectric strength
    NO_EQUILIBRIUM = 4  # no root in 0 < theta < 90 deg (e.g. membrane moment <= 0 while straight)
    CAP_CONTACT = 5  # the membrane still bends the block where the two caps touch


@dataclass(frozen=True)
class Fidelity:
    kind: str  # "closed_form", "arc" or "chord"
    n_strips: int = 64

    def __post_init__(self) -> None:
        if self.kind not in ("closed_form", "arc", "chord"):
            raise ValueError(f"fidelity kind must be 'closed_form', 'arc' or 'chord', got {self.kind!r}")
        if not isinstance(self.n_strips, int) or self.n_strips < 2:
            raise ValueError(f"n_strips must be an integer >= 2, got {self.n_strips!r}")

    @property
    def label(self) -> str:
        return "closed form" if self.kind == "closed_form" else f"{self.kind}, N={self.n_strips}"


TABLE_FIDELITY = Fidelity("chord", 64)
REFERENCE_FIDELITY = Fidelity("chord", 1024)

# Physical ranges accepted as inputs: (low, high) inclusive, SI units.
INPUT_RANGES = {
    "rod_length": (1e-3, 0.1),
    "rod_diameter": (0.05e-3, 3e-3),
    "prestretch_axial": (1.0, 5.0),
    "prestretch_tangential": (1.0, 5.0),
    "film_thickness": (1e-6, 5e-3),
    "relative_permittivity": (1.0, 20.0),
    "rod_modulus": (1e9, 300e9),
    "voltage": (0.0, 20e3),
}


def _checked(name: str, value) -> np.ndarray:
    array = np.asarray(value, dtype=float)
    low, high = INPUT_RANGES[name]
    bad = ~np.isfinite(array) | (array < low) | (array > high)
    if np.any(bad):
        first = array[bad].flat[0] if array.ndim else float(array)
        raise ValueError(f"{name} must lie in [{low:g}, {high:g}] (SI units), got {first!r}")
    return array


@dataclass(frozen=True)
class BlockDesigns:
    """One or many block designs as broadcast arrays (SI units).

    Missing tangential prestretch defaults to 2.5 / lambda_1 (the paper's rule); missing film
    thickness, permittivity and rod modulus come from the material and the calibrated constants.
    """

    rod_length: np.ndarray
    rod_diameter: np.ndarray
    prestretch_axial: np.ndarray
    prestretch_tangential: np.ndarray
    film_thickness: np.ndarray
    relative_permittivity: np.ndarray
    rod_modulus: np.ndarray
    material: OgdenMaterial = ELASTOSIL_2030
    mechanics: Mechanics = CALIBRATED_CONSTANTS.mechanics
    membrane: MembraneArc = field(default=MembraneArc.of(CALIBRATED_CONSTANTS, PAPER_GEOMETRY))
    geometry: BlockGeometry = field(default=PAPER_GEOMETRY)

    @classmethod
    def create(
        cls,
        rod_length,
        rod_diameter,
        prestretch_axial,
        *,
        prestretch_tangential=None,
        material: OgdenMaterial = ELASTOSIL_2030,
        film_thickness=None,
        relative_permittivity=None,
        rod_modulus=None,
        constants: ModelConstants = CALIBRATED_CONSTANTS,
        geometry: BlockGeometry = PAPER_GEOMETRY,
    ) -> "BlockDesigns":
        prestretch_axial = _checked("prestretch_axial", prestretch_axial)
        if prestretch_tangential is None:
            prestretch_tangential = AREAL_PRESTRETCH / prestretch_axial
        if film_thickness is None:
            # The calibrated t0 is ELASTOSIL's effective thickness; other films use their own scale.
            film_thickness = constants.film_thickness * material.nominal_thickness / ELASTOSIL_2030.nominal_thickness
        arrays = np.broadcast_arrays(
            _checked("rod_length", rod_length),
            _checked("rod_diameter", rod_diameter),
            prestretch_axial,
            _checked("prestretch_tangential", prestretch_tangential),
            _checked("film_thickness", film_thickness),
            _checked(
                "relative_permittivity",
                material.relative_permittivity if relative_permittivity is None else relative_permittivity,
            ),
            _checked("rod_modulus", constants.rod_modulus if rod_modulus is None else rod_modulus),
        )
        return cls(*(np.atleast_1d(a).astype(float) for a in arrays), material=material,
                   mechanics=constants.mechanics, membrane=MembraneArc.of(constants, geometry), geometry=geometry)

    @property
    def size(self) -> int:
        return self.rod_length.size

    def select(self, index) -> "BlockDesigns":
        """The designs at ``index`` (an index array or slice), as a new batch."""
        arrays = ("rod_length", "rod_diameter", "prestretch_axial", "prestretch_tangential",
                  "film_thickness", "relative_permittivity", "rod_modulus")
        return dataclasses.replace(self, **{name: np.atleast_1d(getattr(self, name)[index]) for name in arrays})

    @property
    def rod_stiffness(self) -> np.ndarray:
        """Bending stiffness of the two rods, 2 E I / L [N m / rad]."""
        second_moment = math.pi * self.rod_diameter**4 / 64.0
        return 2.0 * self.rod_modulus * second_moment / self.rod_length

    @property
    def permittivity(self) -> np.ndarray:
        return VACUUM_PERMITTIVITY * self.relative_permittivity

    @property
    def contact_angle(self) -> np.ndarray:
        """Bending angle at which the caps' inner faces touch on the bending side [rad]."""
        return self.rod_length / self.membrane.reach


@dataclass(frozen=True)
class EquilibriumResult:
    theta: np.ndarray  # bending angle [rad]; NaN where status != OK
    stiffness: np.ndarray  # tangent rotational stiffness at equilibrium [N m / rad]; NaN if invalid
    status: np.ndarray  # Status codes
    max_field: np.ndarray  # highest field in the film [V/m]

    @property
    def valid(self) -> np.ndarray:
        return self.status == Status.OK

    @property
    def success(self) -> bool:
        return bool(np.all(self.valid))

    @property
    def message(self) -> str:
        """How many designs ended in each status, e.g. 'BREAKDOWN: 2, OK: 82'."""
        return _status_counts(self.status)


def _status_counts(statuses) -> str:
    counts = {Status(s).name: int(n) for s, n in zip(*np.unique(statuses, return_counts=True))}
    return ", ".join(f"{name}: {n}" for name, n in sorted(counts.items()))


def _strip_tension(stretch, film_columns, voltage, material):
    """Axial membrane stress (Ogden minus Maxwell) and thickness for strips at axial stretch."""
    hoop, thickness0, permittivity = film_columns
    thickness = thickness0 / (stretch * hoop)
    maxwell = permittivity * (voltage / thickness) ** 2
    return biaxial_cauchy_stress(material.mu, material.alpha, stretch, hoop) - maxwell, thickness


def _fibre_length(theta, heights, rod_length, kind):
    """Fibre length between the caps and its derivative d l / d theta."""
    arc = rod_length - heights * theta
    if kind == "arc":
        return arc, -heights
    half = 0.5 * theta
    small = np.abs(half) < 1e-4
    safe = np.where(small, 1.0, half)
    sinc = np.where(small, 1.0 - half**2 / 6.0, np.sin(safe) / safe)
    sinc_slope = np.where(small, -half / 3.0, (np.cos(safe) - sinc) / safe)
    return arc * sinc, -heights * sinc + 0.5 * arc * sinc_slope


def _beam_column_factor(u, kind):
    """The compressed rods' stiffness over the constant-curvature rods' (u / tan u for rods clamped in caps
    that are free to rotate). The chord fibres already hold its first-order term -u^2 / 3, added back here so
    that it is not counted twice."""
    safe = np.maximum(u, 1e-2)
    exact = np.where(u < 1e-2, 1.0 - u**2 / 3.0 - u**4 / 45.0, safe / np.tan(safe))
    return exact + u**2 / 3.0 if kind == "chord" else exact


class BlockModel:
    """Equilibrium, stiffness and voltage limit of block designs at one fidelity."""

    def __init__(self, designs: BlockDesigns, fidelity: Fidelity = TABLE_FIDELITY):
        if fidelity.kind == "closed_form" and designs.mechanics.rods != RodLaw.CONSTANT_CURVATURE:
            raise ValueError(f"the closed form models constant-curvature rods only, not {designs.mechanics.rods.value}")
        self.designs = designs
        self.fidelity = fidelity
        self._heights, self._width = designs.membrane.strips(fidelity.n_strips)

    # -- membrane mechanics -------------------------------------------------------------------
    def _film_columns(self, index):
        d = self.designs
        return (d.prestretch_tangential[index], d.film_thickness[index], d.permittivity[index])

    def _strip_state(self, theta, voltage, index):
        """Per-strip stress, thickness and fibre-length slope dl/dtheta at theta for designs[index]."""
        d = self.designs
        rod_length = d.rod_length[index][..., None]
        cols = tuple(c[..., None] for c in self._film_columns(index))
        length, slope = _fibre_length(theta[..., None], self._heights, rod_length, self.fidelity.kind)
        # Clip so fully collapsed fibres stay finite; they are slack and carry no force anyway.
        stretch = np.maximum(d.prestretch_axial[index][..., None] * length / rod_length, 1e-3)
        stress, thickness = _strip_tension(stretch, cols, voltage[..., None], d.material)
        return stress, thickness, slope

    def _residual(self, theta, voltage, index):
        """Membrane moment minus rod moment [N m] for designs[index]."""
        stress, thickness, slope = self._strip_state(theta, voltage, index)
        force = self._width * thickness * np.maximum(stress, 0.0)
        rod_moment = self.designs.rod_stiffness[index] * theta
        if self.designs.mechanics.rods == RodLaw.BEAM_COLUMN:
            length = self.designs.rod_length[index]
            bending = self.designs.rod_stiffness[index] * length  # E I of both rods
            u = np.minimum(0.5 * length * np.sqrt(np.sum(force, axis=-1) / bending), math.pi - 1e-3)
            rod_moment = rod_moment * _beam_column_factor(u, self.fidelity.kind)
        return np.sum(force * -slope, axis=-1) - rod_moment

    # -- solvers ------------------------------------------------------------------------------
    def solve(self, voltage) -> EquilibriumResult:
        """Equilibrium angle of every design at ``voltage`` (scalar or one value per design)."""
        voltage = np.broadcast_to(_checked("voltage", voltage), (self.designs.size,)).astype(float)
        if self.fidelity.kind == "closed_form":
            return self._solve_closed_form(voltage)
        return self._solve_strips(voltage)

    def stroke(self, voltage) -> np.ndarray:
        """theta_0 - theta(V) [rad]; NaN where either state is not a valid equilibrium."""
        return self.solve(0.0).theta - self.solve(voltage).theta

    def _solve_strips(self, voltage) -> EquilibriumResult:
        n = self.designs.size
        index = np.arange(n)
        theta = np.full(n, np.nan)
        status = np.full(n, Status.OK, dtype=int)
        straight = np.zeros(n)
        no_moment = self._residual(straight, voltage, index) <= 0.0
        # Straight, every strip has the same stretch: no moment left means no tension left.
        slack = np.max(self._strip_state(straight, voltage, index)[0], axis=-1) <= 0.0
        status[no_moment] = np.where(slack[no_moment], Status.MEMBRANE_SLACK, Status.NO_EQUILIBRIUM)
        # The root lies before the caps touch (and long before 90 degrees) or the caps rest on each other.
        upper = np.minimum(self.designs.contact_angle, math.pi / 2.0)
        touching = (status == Status.OK) & (self._residual(upper, voltage, index) > 0.0)
        status[touching] = np.where(upper[touching] < math.pi / 2.0, Status.CAP_CONTACT, Status.NO_EQUILIBRIUM)
        solvable = np.flatnonzero(status == Status.OK)
        if solvable.size:
            root = elementwise.find_root(
                lambda x, i, v: self._residual(x, v, i.astype(int)),
                (np.zeros(solvable.size), upper[solvable]),
                args=(solvable.astype(float), voltage[solvable]),
                tolerances={"xatol": 1e-10, "xrtol": 1e-12},
            )
            found = root.success
            theta[solvable[found]] = root.x[found]
            status[solvable[~found]] = Status.NO_EQUILIBRIUM
        return self._classify(theta, voltage, status)

    def _classify(self, theta, voltage, status) -> EquilibriumResult:
        n = self.designs.size
        index = np.arange(n)
        ok = status == Status.OK
        theta_eval = np.where(ok, theta, 0.0)
        _, thickness, _ = self._strip_state(theta_eval, voltage, index)
        max_field = np.max(voltage[:, None] / thickness, axis=-1)
        step = 1e-6
        stiffness = (
            self._residual(theta_eval - step, voltage, index) - self._residual(theta_eval + step, voltage, index)
        ) / (2.0 * step)
        # Order matters: report the most fundamental failure first. Strips that would be compressed wrinkle
        # and carry nothing; at a root the rods' moment is held by the strips still in tension.
        status = np.where(ok & (stiffness <= 0.0), Status.PULL_IN, status)
        breakdown = max_field >= self.designs.material.breakdown_field
        status = np.where((status == Status.OK) & breakdown, Status.BREAKDOWN, status)
        valid = status == Status.OK
        return EquilibriumResult(
            theta=np.where(valid, theta, np.nan),
            stiffness=np.where(valid, stiffness, np.nan),
            status=status,
            max_field=max_field,
        )

    def _solve_closed_form(self, voltage) -> EquilibriumResult:
        """Small-angle estimate: arc model linearised about the straight block (no strips)."""
        d = self.designs
        first, second = d.membrane.moments()
        stretch = d.prestretch_axial
        stress, thickness = _strip_tension(stretch, self._film_columns(slice(None)), voltage, d.material)
        slope = biaxial_cauchy_stress_slope(d.material.mu, d.material.alpha, stretch, d.prestretch_tangential)
        # d(sigma t)/d(lambda_a) including the Maxwell term eps V^2 / t (t ~ 1 / lambda_a).
        force_slope = thickness * (slope - stress / stretch) - 2.0 * d.permittivity * voltage**2 / (thickness * stretch)
        stiffness = d.rod_stiffness + stretch / d.rod_length * force_slope * second
        theta = stress * thickness * first / stiffness
        max_field = voltage / thickness
        status = np.full(d.size, Status.OK, dtype=int)
        status[stress <= 0.0] = Status.MEMBRANE_SLACK
        status[(status == Status.OK) & (stiffness <= 0.0)] = Status.PULL_IN
        status[(status == Status.OK) & (theta >= d.contact_angle)] = Status.CAP_CONTACT
        status[(status == Status.OK) & (max_field >= d.material.breakdown_field)] = Status.BREAKDOWN
        valid = status == Status.OK
        return EquilibriumResult(np.where(valid, theta, np.nan), np.where(valid, stiffness, np.nan), status, max_field)

    # -- voltage limit ------------------------------------------------------------------------
    def voltage_limit(self, *, step: float = 200.0, v_max: float = 12e3, resolution: float = 1.0) -> "VoltageLimit":
        """Highest voltage with a valid equilibrium, per design, and the limit that ends it.

        Scans upward in ``step`` volts from 0 (so the first loss along the loading path is found,
        not a later re-entry) and bisects the last bracket down to ``resolution`` volts.
        """
        n = self.designs.size
        last_ok = np.zeros(n)
        first_bad = np.full(n, np.inf)
        limited_by = np.full(n, Status.OK, dtype=int)
        for v in np.arange(0.0, v_max + step, step):
            open_ = np.isinf(first_bad)
            if not open_.any():
                break
            result = self.solve(np.where(open_, v, last_ok))
            newly_bad = open_ & ~result.valid
            first_bad[newly_bad] = v
            limited_by[newly_bad] = result.status[newly_bad]
            last_ok[open_ & result.valid] = v
        bracketed = np.isfinite(first_bad)
        low, high = last_ok.copy(), np.where(bracketed, first_bad, last_ok)
        while np.any(high - low > resolution):
            mid = 0.5 * (low + high)
            result = self.solve(mid)
            low = np.where(result.valid, mid, low)
            high = np.where(result.valid, high, mid)
            limited_by = np.where(result.valid, limited_by, result.status)
        return VoltageLimit(voltage=np.floor(low / resolution) * resolution, limited_by=limited_by)


@dataclass(frozen=True)
class VoltageLimit:
    voltage: np.ndarray  # highest voltage with a valid equilibrium [V]
    limited_by: np.ndarray  # Status that ends the valid range (OK: valid up to the scan's v_max)

    @property
    def message(self) -> str:
        """Which limit ends how many designs, e.g. 'BREAKDOWN: 84'."""
        return _status_counts(self.limited_by)

"""Fit the block model's unpublished constants to the paper's published numbers.

Unknown: effective film thickness t0 and NiTi modulus E (and, for the ``top_arc`` membrane layout
only, the arc of the cap circle the active membrane covers). Targets (section 2.2.1 of the paper,
FE model values):

* ID 15 (lambda_1 = 1.5, L = 15 mm, D = 0.31 mm): theta_0 = 32.15 deg, stroke 5.29 deg at 2.4 kV;
* IDs 5-7 and 40-42 have similar theta_0;
* the table spans about 3 to 40 deg (smallest: ID 64, largest: ID 21).

Each residual is divided by a tolerance that says how firmly the paper states it; the weighted
least-squares problem is solved with scipy's trust-region reflective method from a fixed start,
so ``python -m planner calibrate`` always reproduces the same constants. The two mass constants
are then solved exactly from the paper's 0.9 g (L = 10 mm) and 1.1 g (L = 15 mm).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from planner.block_model import (
    CALIBRATED_CONSTANTS,
    TABLE_FIDELITY,
    BlockModel,
    Fidelity,
    MembraneLayout,
    Mechanics,
    ModelConstants,
)
from planner.geometry import ROD_LENGTH_VALUES
from planner.mass import MassConstants, component_mass
from planner.table_builder import grid_designs

PAPER_ID15_THETA0 = math.radians(32.15)
PAPER_ID15_STROKE = math.radians(5.29)
PAPER_STROKE_VOLTAGE = 2400.0
PAPER_THETA0_RANGE = (math.radians(3.0), math.radians(40.0))
PAPER_MASS_RANGE = (0.9e-3, 1.1e-3)  # [kg] at L = 10 mm and 15 mm

# (design IDs, tolerance): how tightly each published statement binds the fit.
THETA0_TOLERANCE = math.radians(0.3)
STROKE_TOLERANCE = math.radians(0.2)
SIMILAR_PAIRS = ((5, 40), (6, 41), (7, 42))
SIMILAR_TOLERANCE = math.radians(2.0)
RANGE_IDS = (64, 21)  # smallest and largest theta_0 of the grid
RANGE_LOG_TOLERANCE = 0.15

# One name per residual of ``_residuals``, in its order (leave-one-out studies drop them by index).
TARGET_NAMES = (
    "ID 15 theta_0 = 32.15 deg",
    "ID 15 stroke at 2.4 kV = 5.29 deg",
    *[f"ID {a} theta_0 = ID {b} theta_0" for a, b in SIMILAR_PAIRS],
    "smallest theta_0 (ID 64) = 3 deg",
    "largest theta_0 (ID 21) = 40 deg",
)

# Start and bounds of the fitted parameters: t0 [um], E [GPa], and the top arc's half angle [deg].
INITIAL_GUESS = (100.0, 40.0, 90.0)
BOUNDS = ((10.0, 5.0, 60.0), (400.0, 200.0, 125.0))


@dataclass(frozen=True)
class CalibrationResult:
    constants: ModelConstants
    mass: MassConstants
    residuals: np.ndarray  # weighted residuals at the optimum
    predictions: dict  # the fitted model's values at the targets [rad]
    success: bool
    message: str


def _parameter_count(mechanics: Mechanics) -> int:
    return 3 if mechanics.membrane == MembraneLayout.TOP_ARC else 2


def _constants(x, mechanics: Mechanics) -> ModelConstants:
    half_angle = math.radians(x[2]) if _parameter_count(mechanics) == 3 else None
    return ModelConstants(film_thickness=x[0] * 1e-6, rod_modulus=x[1] * 1e9, mechanics=mechanics,
                          membrane_half_angle=half_angle)


def _predictions(constants: ModelConstants, fidelity: Fidelity) -> dict:
    ids, designs = grid_designs(constants)
    model = BlockModel(designs, fidelity)
    rest = model.solve(0.0).theta
    actuated = model.solve(PAPER_STROKE_VOLTAGE).theta
    at = lambda design: rest[design - 1]  # noqa: E731  (IDs are 1-based rows)
    return {
        "id15_theta0": at(15),
        "id15_stroke": rest[14] - actuated[14],
        "similar_pairs": [(at(a), at(b)) for a, b in SIMILAR_PAIRS],
        "range": (at(RANGE_IDS[0]), at(RANGE_IDS[1])),
    }


def _residuals(predicted: dict) -> np.ndarray:
    values = [
        (predicted["id15_theta0"] - PAPER_ID15_THETA0) / THETA0_TOLERANCE,
        (predicted["id15_stroke"] - PAPER_ID15_STROKE) / STROKE_TOLERANCE,
        *[(a - b) / SIMILAR_TOLERANCE for a, b in predicted["similar_pairs"]],
        *[math.log(p / t) / RANGE_LOG_TOLERANCE if p > 0 else math.inf
          for p, t in zip(predicted["range"], PAPER_THETA0_RANGE)],
    ]
    # An invalid equilibrium (NaN) is a very bad fit, not a crash of the optimizer.
    return np.nan_to_num(np.array(values, dtype=float), nan=1e3, posinf=1e3)


def calibrate_mass(constants: ModelConstants) -> MassConstants:
    """Fixed and per-length mass so the grid's mean mass is 0.9 g at L = 10 mm and 1.1 g at 15 mm."""
    _, designs = grid_designs(constants)
    lengths = (ROD_LENGTH_VALUES[0], ROD_LENGTH_VALUES[-1])
    variable = [np.mean(component_mass(designs)[designs.rod_length == length]) for length in lengths]
    lhs = np.array([[1.0, lengths[0]], [1.0, lengths[1]]])
    fixed, per_length = np.linalg.solve(lhs, np.subtract(PAPER_MASS_RANGE, variable))
    return MassConstants(fixed=float(fixed), per_length=float(per_length))


def target_errors(predicted: dict) -> np.ndarray:
    """Each target's error in degrees (model minus paper; a pair: the first design's angle minus the second's)."""
    paper = [PAPER_ID15_THETA0, PAPER_ID15_STROKE, *[0.0] * len(SIMILAR_PAIRS), *PAPER_THETA0_RANGE]
    model = [predicted["id15_theta0"], predicted["id15_stroke"], *[a - b for a, b in predicted["similar_pairs"]],
             *predicted["range"]]
    return np.degrees(np.subtract(model, paper))


def calibrate(mechanics: Mechanics = CALIBRATED_CONSTANTS.mechanics, fidelity: Fidelity = TABLE_FIDELITY,
              leave_out: tuple[int, ...] = ()) -> CalibrationResult:
    """Weighted least-squares fit of the constants of a model with ``mechanics`` to the paper's published
    points (without the targets ``leave_out``, indices into ``TARGET_NAMES``)."""
    count = _parameter_count(mechanics)
    kept = np.setdiff1d(np.arange(len(TARGET_NAMES)), leave_out)
    fit = least_squares(
        lambda x: _residuals(_predictions(_constants(x, mechanics), fidelity))[kept],
        INITIAL_GUESS[:count],
        bounds=(BOUNDS[0][:count], BOUNDS[1][:count]),
        x_scale=10.0,
        diff_step=1e-4,
    )
    constants = _constants(fit.x, mechanics)
    return CalibrationResult(
        constants=constants,
        mass=calibrate_mass(constants),
        residuals=fit.fun,
        predictions=_predictions(constants, fidelity),
        success=bool(fit.success),
        message=str(fit.message),
    )

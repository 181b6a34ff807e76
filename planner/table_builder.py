"""Generate the 84-design look-up table from the block model (``python -m planner table``)."""
from __future__ import annotations

import numpy as np

from planner.block_model import CALIBRATED_CONSTANTS, TABLE_FIDELITY, BlockDesigns, BlockModel, Fidelity, ModelConstants
from planner.geometry import DESIGN_COUNT
from planner.mass import estimate_mass
from planner.table import BlockTable, design_parameters

TABLE_VOLTAGE_STEP = 300.0  # [V] between tabulated columns


def grid_designs(constants: ModelConstants = CALIBRATED_CONSTANTS, **overrides) -> tuple[np.ndarray, BlockDesigns]:
    """All 84 design IDs and their designs (material, thickness, ... may be overridden)."""
    ids = np.arange(1, DESIGN_COUNT + 1)
    length, diameter, axial, tangential = np.array([design_parameters(int(i)) for i in ids]).T
    designs = BlockDesigns.create(
        length, diameter, axial, prestretch_tangential=tangential, constants=constants, **overrides
    )
    return ids, designs


def build_table(
    fidelity: Fidelity = TABLE_FIDELITY,
    constants: ModelConstants = CALIBRATED_CONSTANTS,
    voltage_step: float = TABLE_VOLTAGE_STEP,
) -> BlockTable:
    """Solve every design at 0 V, at ``voltage_step`` intervals and at its own voltage limit."""
    ids, designs = grid_designs(constants)
    model = BlockModel(designs, fidelity)
    limit = model.voltage_limit()
    voltages = np.arange(0.0, np.max(limit.voltage) + 0.5 * voltage_step, voltage_step)
    voltages = voltages[voltages <= np.max(limit.voltage)]
    theta = np.column_stack([model.solve(v).theta for v in voltages])
    rest = model.solve(0.0)
    at_limit = model.solve(limit.voltage)
    return BlockTable(
        ids=ids,
        rod_length=designs.rod_length,
        rod_diameter=designs.rod_diameter,
        prestretch_axial=designs.prestretch_axial,
        prestretch_tangential=designs.prestretch_tangential,
        theta0=rest.theta,
        stiffness=rest.stiffness,
        mass=estimate_mass(designs),
        safe_voltage=limit.voltage,
        theta_at_safe_voltage=at_limit.theta,
        voltages=voltages,
        theta=theta,
    )

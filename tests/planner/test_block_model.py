"""Block physics model: the paper's published points, trends, fidelities, limits and bad inputs."""
import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.block_model import (
    CALIBRATED_CONSTANTS,
    INPUT_RANGES,
    REFERENCE_FIDELITY,
    BlockDesigns,
    BlockModel,
    Fidelity,
    MembraneArc,
    MembraneLayout,
    Mechanics,
    ModelConstants,
    RodLaw,
    Status,
)
from planner.geometry import PAPER_GEOMETRY, PRESTRETCH_AXIAL_VALUES, BlockGeometry
from planner.materials import ELASTOSIL_2030, VHB_4910, material_by_name
from planner.table import design_id, load_table

pytestmark = pytest.mark.fast

DEG = math.pi / 180.0


@pytest.fixture(scope="module")
def table():
    return load_table()


def grid(table, values):
    """(D, L, lambda_1) cube of a per-design quantity, in ID order."""
    return np.asarray(values).reshape(4, 3, 7)


def test_id15_matches_the_paper(table):
    row = table.design(15)
    assert (row.prestretch_axial, row.rod_length, row.rod_diameter) == (1.5, 15e-3, 0.31e-3)
    assert row.theta0 == pytest.approx(32.15 * DEG, rel=0.058)
    actuated, valid = table.angle_at([15], 2400.0)
    assert valid[0]
    assert row.theta0 - actuated[0] == pytest.approx(5.29 * DEG, rel=0.25)


def test_four_id15_blocks_in_series_match_the_paper(table):
    # The paper's kinematic model: 130.92 deg unactuated, 100.8 deg at 2.4 kV (experiment 107.4).
    actuated, _ = table.angle_at([15] * 4, 2400.0)
    assert 4 * table.design(15).theta0 == pytest.approx(130.92 * DEG, rel=0.058)
    assert actuated.sum() == pytest.approx(100.8 * DEG, rel=0.1)


def test_table_spans_the_papers_range(table):
    theta0 = np.degrees(table.theta0)
    assert 2.0 <= theta0.min() <= 4.0  # the paper: from about 3 deg (give or take 1 deg)
    assert 35.0 <= theta0.max() <= 50.0
    assert table.theta0.argmin() + 1 == design_id(0, 0, 3) and table.theta0.argmax() + 1 == design_id(6, 2, 0)


def test_trends_of_section_2_2_1(table):
    theta0 = grid(table, table.theta0)
    assert np.all(np.diff(theta0, axis=2) > 0)  # lambda_1 up -> theta_0 up
    assert np.all(np.diff(theta0, axis=1) > 0)  # L up -> theta_0 up
    assert np.all(np.diff(theta0, axis=0) < 0)  # D up -> theta_0 down
    stiffness = grid(table, table.stiffness)
    assert np.all(np.diff(stiffness, axis=0) > 0)  # D up -> stiffer
    assert np.all(np.diff(stiffness, axis=1) < 0)  # L up -> softer
    stroke = grid(table, table.theta0 - table.angle_at(table.ids, 2400.0)[0])
    assert np.all(np.diff(stroke, axis=0) < 0)  # D up -> smaller stroke
    assert np.all(np.diff(stroke, axis=1) > 0)  # L up -> larger stroke
    lam = np.array(PRESTRETCH_AXIAL_VALUES)
    for curve in theta0[2:].reshape(-1, 7):  # near-linear in lambda_1 for the larger D
        fit = np.polyval(np.polyfit(lam, curve, 1), lam)
        assert 1.0 - np.sum((curve - fit) ** 2) / np.sum((curve - curve.mean()) ** 2) > 0.99


def test_ids_5_to_7_resemble_ids_40_to_42(table):
    short_thin = table.theta0[table.index_of([5, 6, 7])]
    long_thicker = table.theta0[table.index_of([40, 41, 42])]
    np.testing.assert_allclose(short_thin, long_thicker, rtol=0.05)  # "similar": within 5 %


def test_larger_prestretch_would_make_the_caps_collide(table):
    # The paper keeps lambda_1 <= 2.1 because "larger stretching ratios will cause collisions between the
    # linking caps": every tabulated design stays clear of contact, the thinnest rods touch just beyond 2.1.
    designs = BlockDesigns.create(table.rod_length, table.rod_diameter, table.prestretch_axial)
    assert np.all(table.theta0 < designs.contact_angle)
    beyond = BlockModel(BlockDesigns.create([10e-3, 12.5e-3, 15e-3], 0.31e-3, 2.2)).solve(0.0)
    assert np.all(beyond.status == Status.CAP_CONTACT) and np.all(np.isnan(beyond.theta))
    assert beyond.message == "CAP_CONTACT: 3"


def test_the_membrane_arc_follows_from_the_rod_height():
    # The active membrane runs around the far side of the caps from one rod to the other: with the rods on the
    # diameter it is the half circle of the paper's validation blocks; at h = 8 mm it ends level with the rods.
    centred = MembraneArc.of(CALIBRATED_CONSTANTS, BlockGeometry(rod_depth=12.5e-3))
    assert centred.half_angle == pytest.approx(math.pi / 2) and centred.length == pytest.approx(math.pi * 12.5e-3)
    paper = MembraneArc.of(CALIBRATED_CONSTANTS, PAPER_GEOMETRY)
    assert paper.centre_offset + paper.radius * math.cos(paper.half_angle) == pytest.approx(0.0, abs=1e-12)
    assert paper.reach == pytest.approx(17e-3)  # the caps touch at theta = L / 17 mm
    heights, _ = paper.strips(64)
    assert np.all(heights > 0.0)  # every strip pulls toward the bend


def test_a_partly_wrinkled_membrane_still_holds_the_block(table):
    # Strips that the bend would compress wrinkle and carry nothing; the others hold the rods' moment.
    row = table.design(21)
    model = BlockModel(BlockDesigns.create(row.rod_length, row.rod_diameter, row.prestretch_axial))
    result = model.solve(0.0)
    stress = model._strip_state(result.theta, np.zeros(1), np.arange(1))[0]
    assert result.success and np.any(stress <= 0.0) and np.any(stress > 0.0)


def test_model_constants_match_their_layout():
    with pytest.raises(ValueError, match="top_arc layout needs membrane_half_angle"):
        ModelConstants(90e-6, 30e9, Mechanics(MembraneLayout.TOP_ARC))
    with pytest.raises(ValueError, match="belongs to the top_arc layout only"):
        ModelConstants(90e-6, 30e9, Mechanics(MembraneLayout.BEYOND_RODS), membrane_half_angle=1.0)
    with pytest.raises(ValueError, match="'sideways' is not a valid MembraneLayout"):
        Mechanics("sideways")
    beam_column = ModelConstants(90e-6, 30e9, Mechanics(rods=RodLaw.BEAM_COLUMN))
    with pytest.raises(ValueError, match="closed form models constant-curvature rods only"):
        BlockModel(BlockDesigns.create(15e-3, 0.31e-3, 1.5, constants=beam_column), Fidelity("closed_form"))


def test_mass_matches_the_paper(table):
    assert np.all((table.mass > 0.8e-3) & (table.mass < 1.2e-3))
    assert table.mass[table.rod_length == 10e-3].mean() == pytest.approx(0.9e-3, rel=1e-4)
    assert table.mass[table.rod_length == 15e-3].mean() == pytest.approx(1.1e-3, rel=1e-4)


def test_fidelities_agree_with_the_reference():
    designs = BlockDesigns.create([10e-3, 15e-3], [0.31e-3, 0.763e-3], [2.1, 1.5])
    model = BlockModel(designs, REFERENCE_FIDELITY)
    reference = model.solve(1800.0).theta
    for fidelity, tolerance in ((Fidelity("chord", 16), 0.03), (Fidelity("arc", 64), 0.15)):
        np.testing.assert_allclose(BlockModel(designs, fidelity).solve(1800.0).theta, reference, rtol=tolerance)
    # The closed form is linear about the straight block: it holds while every strip keeps its tension, and
    # it under-bends a block whose far strips wrinkle (its linear law keeps them pulling against the bend).
    closed = BlockModel(designs, Fidelity("closed_form")).solve(1800.0).theta
    wrinkled = np.min(model._strip_state(reference, np.full(2, 1800.0), np.arange(2))[0], axis=-1) <= 0.0
    assert wrinkled.tolist() == [True, False]
    np.testing.assert_allclose(closed[~wrinkled], reference[~wrinkled], rtol=0.3)
    assert np.all(closed[wrinkled] < reference[wrinkled])


def test_calibration_reproduces_the_shipped_constants():
    from planner.model_calibration import calibrate

    result = calibrate()
    assert result.success and result.constants.mechanics == CALIBRATED_CONSTANTS.mechanics
    assert result.constants.membrane_half_angle is None  # the shipped layout's arc follows from h, not a fit
    fitted, shipped = result.constants, CALIBRATED_CONSTANTS
    np.testing.assert_allclose([fitted.film_thickness, fitted.rod_modulus], [shipped.film_thickness, shipped.rod_modulus],
                               rtol=5e-3)


@pytest.mark.parametrize("design", [1, 15, 21, 57, 64, 84])
def test_voltage_sweep_past_the_limit_reports_the_limit(table, design):
    row = table.design(design)
    model = BlockModel(BlockDesigns.create(row.rod_length, row.rod_diameter, row.prestretch_axial))
    limit = model.voltage_limit()
    assert limit.voltage[0] == pytest.approx(row.safe_voltage)
    assert limit.limited_by[0] == Status.BREAKDOWN and limit.message == "BREAKDOWN: 1"
    previous = math.inf
    for voltage in np.linspace(0.0, 1.5 * row.safe_voltage, 16):
        result = model.solve(voltage)
        if voltage <= row.safe_voltage:
            assert result.success and 0.0 < result.theta[0] < previous and result.stiffness[0] > 0.0
            previous = result.theta[0]
        else:
            assert not result.success and math.isnan(result.theta[0]) and math.isnan(result.stiffness[0])
            assert result.status[0] == Status.BREAKDOWN and result.max_field[0] >= ELASTOSIL_2030.breakdown_field
            assert "BREAKDOWN" in result.message


def test_without_breakdown_the_membrane_loses_tension():
    # A film that never breaks down relaxes the block until the membrane goes slack.
    strong = dataclasses.replace(ELASTOSIL_2030, breakdown_field=1e12)
    model = BlockModel(BlockDesigns.create([10e-3, 15e-3], [0.31e-3, 0.62e-3], [1.5, 2.1], material=strong))
    limit = model.voltage_limit(v_max=20e3)
    assert np.all(limit.limited_by == Status.MEMBRANE_SLACK)
    beyond = model.solve(limit.voltage + 10.0)
    assert np.all(beyond.status == Status.MEMBRANE_SLACK) and np.all(np.isnan(beyond.theta))
    assert np.all(model.solve(limit.voltage).valid)


def test_vhb_membrane_gives_a_valid_block():
    model = BlockModel(BlockDesigns.create(15e-3, 0.44e-3, 1.8, material=material_by_name("VHB4910")))
    rest, actuated = model.solve(0.0), model.solve(5000.0)
    assert rest.success and actuated.success and 0.0 < actuated.theta[0] < rest.theta[0]
    assert VHB_4910.relative_permittivity == 4.7


@pytest.mark.parametrize(
    "name, value",
    [("rod_length", -0.01), ("rod_diameter", 0.0), ("prestretch_axial", 0.8), ("prestretch_tangential", 9.0),
     ("film_thickness", 0.0), ("relative_permittivity", 0.5), ("rod_modulus", 1e15)],
)
def test_out_of_range_inputs_name_the_parameter(name, value):
    arguments = {"rod_length": 15e-3, "rod_diameter": 0.31e-3, "prestretch_axial": 1.5, name: value}
    with pytest.raises(ValueError, match=name):
        BlockDesigns.create(**arguments)


@pytest.mark.parametrize("voltage", [-1.0, math.nan, 1e6])
def test_bad_voltage_names_the_parameter(voltage):
    with pytest.raises(ValueError, match="voltage"):
        BlockModel(BlockDesigns.create(15e-3, 0.31e-3, 1.5)).solve(voltage)


def test_unknown_material_and_fidelity_are_rejected():
    with pytest.raises(ValueError, match="material 'rubber' unknown"):
        material_by_name("rubber")
    with pytest.raises(ValueError, match="fidelity kind"):
        Fidelity("fem")
    with pytest.raises(ValueError, match="n_strips"):
        Fidelity("arc", 1)


@settings(max_examples=25, deadline=None)
@given(
    rod_length=st.floats(*INPUT_RANGES["rod_length"]),
    rod_diameter=st.floats(0.2e-3, 1e-3),
    prestretch=st.floats(1.2, 2.5),
    voltage=st.floats(0.0, 8000.0),
)
def test_solve_never_returns_a_silently_wrong_angle(rod_length, rod_diameter, prestretch, voltage):
    designs = BlockDesigns.create(rod_length, rod_diameter, prestretch)
    result = BlockModel(designs, Fidelity("chord", 16)).solve(voltage)
    if result.success:
        theta = result.theta[0]
        assert 0.0 < theta < math.pi / 2 and result.stiffness[0] > 0.0
        assert result.max_field[0] < ELASTOSIL_2030.breakdown_field
        # the solver's own moment balance (membrane minus rods) at the angle it returned
        residual = BlockModel(designs, Fidelity("chord", 16))._residual(np.array([theta]), np.array([voltage]), [0])
        assert abs(residual[0]) <= 1e-9 * designs.rod_stiffness[0] + 1e-12
    else:
        assert math.isnan(result.theta[0]) and result.status[0] != Status.OK


def test_stroke_is_nan_beyond_the_limit():
    model = BlockModel(BlockDesigns.create(15e-3, 0.31e-3, 1.5))
    assert model.stroke(2400.0)[0] == pytest.approx(5.29 * DEG, rel=0.25)
    assert math.isnan(model.stroke(9000.0)[0])

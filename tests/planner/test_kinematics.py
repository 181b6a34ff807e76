"""Piecewise-constant-curvature kinematics against hand-computed cases."""
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from planner import kinematics
from planner.assembly import Chain, PlacedBlock, load_assembly
from planner.kinematics import (
    BLOCK_RADIUS,
    CAP_LENGTH,
    assembly_centerlines,
    block_end_offsets,
    block_transforms,
    chain_blocks,
    chain_frames,
    chain_shape,
    design_parameters,
    planar_chain,
)
from planner.table import load_table

pytestmark = pytest.mark.fast

C = CAP_LENGTH


def test_single_block_end_is_cap_chord_cap():
    theta, length = 0.6, 0.015
    expected_x = length * (1 - math.cos(theta)) / theta + C * math.sin(theta)
    expected_z = C + length * math.sin(theta) / theta + C * math.cos(theta)
    planar = planar_chain([theta], [length])
    np.testing.assert_allclose(planar.ends[-1], [expected_x, expected_z], atol=1e-15)
    assert planar.end_headings[-1] == pytest.approx(theta)
    spatial = chain_shape([theta], [length])
    np.testing.assert_allclose(spatial.positions[-1], [expected_x, 0.0, expected_z], atol=1e-15)


def test_arc_samples_lie_on_the_bending_circle():
    theta, length = 1.1, 0.02
    shape = planar_chain([theta], [length], samples_per_block=12)
    radius = length / theta
    arc = shape.points[2:-1]  # after the first cap's end, before the second cap's end
    centre = np.array([radius, C])
    np.testing.assert_allclose(np.linalg.norm(arc - centre, axis=-1), radius, rtol=1e-12)


def test_straight_block_has_length_of_rod_and_two_caps():
    shape = planar_chain([0.0], [0.02])
    assert np.all(np.isfinite(shape.points))
    np.testing.assert_allclose(shape.ends[-1], [0.0, 0.02 + 2 * C], atol=1e-15)
    np.testing.assert_allclose(shape.points[:, 0], 0.0, atol=1e-15)


def test_tiny_angles_are_continuous_with_zero():
    x0, z0 = block_end_offsets(0.0, 0.015)
    x1, z1 = block_end_offsets(1e-9, 0.015)
    assert x1 == pytest.approx(x0 + (0.015 / 2 + C) * 1e-9, abs=1e-15)
    assert z1 == pytest.approx(z0, abs=1e-15)


def test_constant_curvature_chain_adds_the_angles():
    theta = math.radians(32.15)
    shape = planar_chain(np.full(4, theta), 0.015)
    assert shape.end_headings[-1] == pytest.approx(4 * theta)
    assert np.all(np.diff(shape.headings) >= 0)


def test_worm_of_half_turns_straightens_out():
    # phi = 180 deg flips the bending side: two identical blocks make a point-symmetric S whose end
    # tangent is parallel to the base axis again; a longer worm advances along a straight line.
    two = planar_chain([0.5, 0.5], 0.015, [0.0, math.pi])
    assert two.end_headings[-1] == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_allclose(two.ends[2], 2 * two.ends[1], atol=1e-15)
    worm = planar_chain(np.full(8, 0.5), 0.015, [0.0] + [math.pi] * 7)
    direction = worm.ends[2] / np.linalg.norm(worm.ends[2])
    np.testing.assert_allclose(worm.ends[::2] @ [direction[1], -direction[0]], 0.0, atol=1e-15)
    np.testing.assert_allclose(worm.end_headings[::2], 0.0, atol=1e-15)
    spatial = chain_shape(np.full(8, 0.5), 0.015, [0.0] + [math.pi] * 7)
    np.testing.assert_allclose(spatial.positions[:, 1], 0.0, atol=1e-15)
    np.testing.assert_allclose(spatial.positions[:, [0, 2]], worm.ends, atol=1e-15)


def test_helix_block_ends_follow_the_screw_motion_of_one_block():
    theta, length, turn, blocks = 0.4, 0.015, math.radians(30), 30
    shape = chain_shape(np.full(blocks, theta), length, turn)
    one = block_transforms([theta], [length], [turn])[0]
    rotation, translation = one[:3, :3], one[:3, 3]
    rotvec = Rotation.from_matrix(rotation).as_rotvec()
    angle = np.linalg.norm(rotvec)
    axis = rotvec / angle
    pitch = axis @ translation
    point_on_axis = np.linalg.lstsq(np.eye(3) - rotation, translation - pitch * axis, rcond=None)[0]
    k = np.arange(blocks + 1)
    helix = (
        point_on_axis
        + Rotation.from_rotvec(np.outer(k * angle, axis)).apply(-point_on_axis)
        + np.outer(k * pitch, axis)
    )
    np.testing.assert_allclose(shape.positions, helix, atol=1e-12)
    # In projection along the screw axis the block ends lie on one circle.
    radial = shape.positions - point_on_axis
    radial -= np.outer(radial @ axis, axis)
    base_radial = point_on_axis - (point_on_axis @ axis) * axis
    np.testing.assert_allclose(np.linalg.norm(radial, axis=-1), np.linalg.norm(base_radial), rtol=1e-9)


def test_spatial_agrees_with_planar_for_half_turns():
    rng = np.random.default_rng(1)
    theta = rng.uniform(-0.2, 1.0, (3, 6))
    length = rng.choice([0.01, 0.015, 0.02], (3, 6))
    phi = rng.choice([0.0, math.pi], (3, 6))
    planar = planar_chain(theta, length, phi)
    spatial = chain_shape(theta, length, phi)
    np.testing.assert_allclose(spatial.points, np.insert(planar.points, 1, 0.0, axis=-1), atol=1e-14)  # y = 0
    tangents = spatial.sample_rotations()[..., :, 2]
    expected = np.stack([np.sin(planar.headings), np.zeros_like(planar.headings), np.cos(planar.headings)], -1)
    np.testing.assert_allclose(tangents, expected, atol=1e-14)


def test_batch_agrees_with_a_loop_over_designs():
    rng = np.random.default_rng(2)
    theta = rng.uniform(0.0, 1.2, (4, 5, 7))
    length = rng.choice([0.01, 0.015, 0.02], (4, 5, 7))
    phi = rng.integers(0, 12, (4, 5, 7)) * math.radians(30)
    batch = chain_shape(theta, length, phi)
    flips = rng.choice([0.0, math.pi], (4, 5, 7))
    planar_batch = planar_chain(theta, length, flips)
    for index in np.ndindex(4, 5):
        single = chain_shape(theta[index], length[index], phi[index])
        np.testing.assert_allclose(batch.points[index], single.points, atol=1e-15)
        np.testing.assert_allclose(batch.frames[index], single.frames, atol=1e-15)
        planar = planar_chain(theta[index], length[index], flips[index])
        np.testing.assert_allclose(planar_batch.points[index], planar.points, atol=1e-15)


def test_chunked_evaluation_matches_one_pass(monkeypatch):
    rng = np.random.default_rng(5)
    theta = rng.uniform(0.0, 1.0, (2, 5, 4))
    phi = rng.integers(0, 12, (2, 5, 4)) * math.radians(30)
    whole = chain_shape(theta, 0.015, phi), planar_chain(theta, 0.015, 0.0), chain_frames(theta, 0.015, phi)
    monkeypatch.setattr(kinematics, "CHUNK", 3)  # 10 chains in passes of 3, 3, 3, 1
    chunked = chain_shape(theta, 0.015, phi), planar_chain(theta, 0.015, 0.0), chain_frames(theta, 0.015, phi)
    np.testing.assert_allclose(chunked[0].points, whole[0].points, rtol=0, atol=1e-15)
    np.testing.assert_allclose(chunked[0].rotations, whole[0].rotations, rtol=0, atol=1e-15)
    np.testing.assert_allclose(chunked[1].points, whole[1].points, rtol=0, atol=1e-15)
    np.testing.assert_allclose(chunked[1].headings, whole[1].headings, rtol=0, atol=1e-15)
    np.testing.assert_allclose(chunked[2][1], whole[2][1], rtol=0, atol=1e-15)


def test_empty_batches_keep_their_shape():
    assert chain_shape(np.zeros((0, 4)), 0.015).points.shape == (0, 41, 3)
    assert planar_chain(np.zeros((0, 4)), 0.015).points.shape == (0, 41, 2)
    assert chain_frames(np.zeros((2, 0, 4)), 0.015)[0].shape == (2, 0, 5, 3, 3)


def test_composed_block_transforms_give_the_end_frames():
    rng = np.random.default_rng(3)
    theta, length = rng.uniform(0, 1, 5), np.full(5, 0.015)
    phi = rng.integers(0, 12, 5) * math.radians(30)
    frame = np.eye(4)
    for transform in block_transforms(theta, length, phi):
        frame = frame @ transform
    np.testing.assert_allclose(chain_shape(theta, length, phi).frames[-1], frame, atol=1e-15)


@settings(max_examples=40, deadline=None)
@given(
    theta=st.lists(st.floats(-math.pi, math.pi), min_size=1, max_size=12),
    steps=st.lists(st.integers(0, 11), min_size=12, max_size=12),
    length=st.sampled_from([10e-3, 12.5e-3, 15e-3]),
)
def test_frames_stay_rigid_and_the_centerline_keeps_its_length(theta, steps, length):
    n = len(theta)
    shape = chain_shape(theta, length, np.array(steps[:n]) * math.radians(30), samples_per_block=40)
    rotations = shape.rotations
    np.testing.assert_allclose(rotations @ np.swapaxes(rotations, -1, -2), np.broadcast_to(np.eye(3), rotations.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rotations), 1.0, atol=1e-12)
    polyline = np.linalg.norm(np.diff(shape.points, axis=0), axis=-1).sum()
    total = n * (length + 2 * CAP_LENGTH)
    assert polyline <= total + 1e-12
    assert polyline == pytest.approx(total, rel=2e-3)  # chords of 38 arc steps per block


def test_frames_only_path_matches_the_full_shape():
    rng = np.random.default_rng(4)
    theta = rng.uniform(-0.5, 1.0, (6, 9))
    phi = rng.integers(0, 12, (6, 9)) * math.radians(30)
    rotations, positions = chain_frames(theta, 0.0125, phi)
    full = chain_shape(theta, 0.0125, phi, samples_per_block=3)
    np.testing.assert_allclose(rotations, full.rotations, atol=1e-15)
    np.testing.assert_allclose(positions, full.positions, atol=1e-15)
    assert full.points.shape == (6, 1 + 9 * 3, 3)
    np.testing.assert_allclose(full.points[:, 3::3], positions[:, 1:], atol=1e-15)  # each block's last sample is its end


def test_periphery_points_are_radial_and_collinear():
    shape = planar_chain([0.7, 0.3], 0.015, [0.0, math.pi])
    plus, minus = shape.periphery()
    np.testing.assert_allclose(np.linalg.norm(plus - shape.points, axis=-1), BLOCK_RADIUS)
    np.testing.assert_allclose((plus + minus) / 2, shape.points, atol=1e-15)
    tangent = np.stack([np.sin(shape.headings), np.cos(shape.headings)], -1)
    np.testing.assert_allclose(np.sum((plus - shape.points) * tangent, -1), 0.0, atol=1e-15)
    straight_plus, _ = planar_chain([0.0], 0.015).periphery()
    np.testing.assert_allclose(straight_plus[:, 0], BLOCK_RADIUS)  # +x side at phi = 0


def test_tube_surrounds_the_centerline_at_the_block_radius():
    shape = chain_shape([0.5, 0.4, 0.9], 0.015, [0.0, math.radians(90), math.radians(210)])
    tube = shape.tube(around=8)
    assert tube.shape == (shape.points.shape[0], 8, 3)
    offset = tube - shape.points[:, None, :]
    np.testing.assert_allclose(np.linalg.norm(offset, axis=-1), BLOCK_RADIUS)
    tangent = shape.sample_rotations()[:, :, 2]
    np.testing.assert_allclose(np.einsum("pkj,pj->pk", offset, tangent), 0.0, atol=1e-15)


def test_transformed_shape_moves_points_and_frames():
    shape = chain_shape([0.5, 0.2], 0.015, [0.0, math.radians(60)])
    rotation = Rotation.from_euler("x", 180, degrees=True).as_matrix()
    moved = shape.transformed(rotation, [0.03, 0.0, 0.1])
    np.testing.assert_allclose(moved.points, shape.points @ rotation.T + [0.03, 0.0, 0.1])
    parent = np.eye(4)
    parent[:3, :3], parent[:3, 3] = rotation, [0.03, 0.0, 0.1]
    np.testing.assert_allclose(moved.frames, parent @ shape.frames, atol=1e-15)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: planar_chain([0.3, 0.3], 0.015, [0.0, math.radians(30)]), "phi must be 0 or pi"),
        (lambda: chain_shape([0.3], [0.0]), "length"),
        (lambda: chain_shape([np.nan], [0.015]), "theta must be finite"),
        (lambda: chain_shape(np.zeros(3), np.full(2, 0.015)), "do not broadcast"),
        (lambda: chain_shape(np.zeros(0), 0.015), "at least one block"),
        (lambda: chain_shape(0.3, 0.015), "scalars"),
        (lambda: planar_chain([0.3], 0.015, samples_per_block=2), "samples_per_block"),
        (lambda: chain_shape([0.3], 0.015).tube(around=2), "around"),
    ],
)
def test_bad_input_is_named(call, message):
    with pytest.raises(ValueError, match=message):
        call()


# ----------------------------------------------------------------------- look-up table and assemblies
ASSEMBLIES = Path(__file__).resolve().parents[2] / "config" / "assemblies"


@pytest.fixture(scope="module")
def table():
    return load_table()


def test_design_parameters_batch_matches_the_table(table):
    ids = np.array([[15, 57, 36], [1, 84, 15]])
    theta, length, valid = design_parameters(table, ids)
    assert theta.shape == length.shape == valid.shape == (2, 3) and valid.all()
    assert theta[0, 0] == table.theta0[table.index_of([15])[0]]
    actuated, _, actuated_valid = design_parameters(table, ids, voltage=1200.0)
    expected, expected_valid = table.angle_at(ids.ravel(), 1200.0)
    np.testing.assert_array_equal(actuated.ravel(), expected)
    np.testing.assert_array_equal(actuated_valid.ravel(), expected_valid)
    single = design_parameters(table, 15, voltage=1200.0)
    assert [np.shape(a) for a in single] == [(), (), ()] and single[0] == expected[0]
    with pytest.raises(ValueError, match="unknown design IDs"):
        design_parameters(table, [15, 99])


def test_figure2_arc_bends_by_four_theta0_in_the_assembly_frame(table):
    assembly = load_assembly(ASSEMBLIES / "figure2_arc.yaml")
    shape = assembly_centerlines(assembly, table, {})["arc"]
    theta0 = table.theta0[table.index_of([15])[0]]
    np.testing.assert_allclose(shape.theta, theta0)
    tangent = shape.rotations[-1][:, 2]
    assert math.atan2(tangent[0], tangent[2]) == pytest.approx(4 * theta0)
    assert shape.valid.all()
    np.testing.assert_allclose(shape.points[:, 1], 0.0, atol=1e-15)


def test_actuation_lowers_the_angles_and_flags_voltages_beyond_safe(table):
    assembly = load_assembly(ASSEMBLIES / "figure2_arc.yaml")
    rest = assembly_centerlines(assembly, table, {"main": 0.0})["arc"]
    safe = float(table.safe_voltage[table.index_of([15])[0]])
    actuated = assembly_centerlines(assembly, table, {"main": 0.9 * safe})["arc"]
    beyond = assembly_centerlines(assembly, table, {"main": safe + 100.0})["arc"]
    assert np.all(actuated.theta < rest.theta) and actuated.valid.all()
    assert not beyond.valid.any()


def test_calibration_offsets_apply_by_serial(table):
    chain = Chain("finger", "main", (PlacedBlock(15, serial="A7"), PlacedBlock(15, serial="B2"), PlacedBlock(15)))
    theta, _, _, _ = chain_blocks(chain, table)
    calibrated, _, _, _ = chain_blocks(chain, table, calibration={"A7": 0.05, "C9": 1.0})
    np.testing.assert_allclose(calibrated - theta, [0.05, 0.0, 0.0])


def test_base_pose_places_and_turns_the_chain(table):
    gripper = load_assembly(ASSEMBLIES / "gripper.yaml")
    shapes = assembly_centerlines(gripper, table, {"front": 500.0}, samples_per_block=5)
    assert set(shapes) == {"front_left", "front_right", "back_left", "back_right"}
    right = shapes["front_right"]  # turned 180 deg about y: grows down (-z), bends toward -x
    np.testing.assert_allclose(right.points[0], [0.03, 0.015, 0.0])
    assert right.points.shape == (1 + 4 * 5, 3)
    assert right.positions[-1][2] < -0.04 and right.positions[-1][0] < 0.03
    left = shapes["front_left"]  # mirror image about the x = 0 plane
    np.testing.assert_allclose(left.points * [-1, 1, 1], right.points, atol=1e-15)


def test_paper_assemblies_load_as_described():
    trunk = load_assembly(ASSEMBLIES / "trunk.yaml").chains
    assert len(trunk) == 1 and trunk[0].design_ids == (57,) * 4 + (36,) * 2 + (15,) * 11
    legged = load_assembly(ASSEMBLIES / "legged.yaml")
    assert [c.name for c in legged.chains] == ["leg_front_left", "leg_front_right", "leg_rear_left", "leg_rear_right"]
    assert legged.hv_channels == tuple(c.name for c in legged.chains)
    assert all(c.design_ids == (57, 57) for c in legged.chains)
    helix = load_assembly(ASSEMBLIES / "figure2_helix.yaml").chains[0]
    worm = load_assembly(ASSEMBLIES / "figure2_worm.yaml").chains[0]
    assert [b.rotation_steps for b in helix.blocks] == [0, 1, 1, 1]
    assert [b.rotation_steps for b in worm.blocks] == [0, 6, 6, 6]

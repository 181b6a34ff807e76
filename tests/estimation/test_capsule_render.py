"""The capsule renderer (tests/estimation/capsule_render.py), the second independent source of test images,
against closed forms and against the reference renderer (estimation/render.py)."""
import math

import numpy as np
import pytest
from capsule_render import capsule_chain, capsule_silhouette
from estimation_scenes import make_chain

from estimation.render import render_chain, to_binary
from estimation.view import ImagePose
from planner.geometry import PAPER_GEOMETRY

pytestmark = pytest.mark.fast

PIXEL = 0.25e-3
R, CAP = PAPER_GEOMETRY.radius, PAPER_GEOMETRY.cap_length


def test_a_straight_block_is_a_rectangle_of_the_tube_width_and_the_block_length():
    pose = ImagePose(0.05, 0.01, math.pi / 2)  # grows down from (50, 10) mm
    coverage, _ = capsule_silhouette([0.0], [15e-3], [0], PIXEL, frame=(pose, (200, 400)))
    rows = np.flatnonzero(coverage.max(axis=1) > 0)
    columns = np.flatnonzero(coverage.max(axis=0) > 0)
    assert (rows[0], rows[-1] + 1) == (40, 120)  # 10 mm to 30 mm: cap + 15 mm + cap
    assert (columns[0], columns[-1] + 1) == (150, 250)  # 25 mm wide, centred on x = 50 mm
    assert coverage.sum() * PIXEL**2 == pytest.approx(25e-3 * 20e-3, rel=1e-3)


@pytest.mark.parametrize("degrees", [5.0, 32.0, 44.0])
def test_a_bent_block_has_the_area_of_its_annulus_sector_and_caps(degrees):
    coverage, _ = capsule_silhouette([math.radians(degrees)], [15e-3], [0], PIXEL, angle=1.0)
    expected = 2 * 15e-3 * R + 2 * (2 * R * CAP)  # the sector between radii L/theta -+ r, and two caps
    assert coverage.sum() * PIXEL**2 == pytest.approx(expected, rel=2e-3)


def test_the_bend_goes_to_the_chains_plus_x_and_mirrors_with_the_pose():
    plain, _ = capsule_silhouette([math.radians(40)], [15e-3], [0], PIXEL, frame=(ImagePose(0.05, 0.01, math.pi / 2), (200, 400)))
    mirrored, _ = capsule_silhouette([math.radians(40)], [15e-3], [0], PIXEL,
                                     frame=(ImagePose(0.05, 0.01, math.pi / 2, True), (200, 400)))
    columns = np.arange(400) + 0.5
    # hanging down, the chain's +x is image -x (left); seen from the other side, right
    assert (plain.sum(axis=0) @ columns) / plain.sum() * PIXEL < 0.05 < (mirrored.sum(axis=0) @ columns) / mirrored.sum() * PIXEL
    np.testing.assert_allclose(plain[:, ::-1], mirrored, atol=1e-9)


@pytest.mark.parametrize("ids, steps, limit", [
    ([57, 36, 15, 15, 22], [0, 0, 0, 0, 0], 8),  # planar: the two agree to a few pixels of the outline
    ([57, 36, 15, 15, 22], [0, 0, 6, 0, 0], 8),
    ([36, 15, 22], [0, 2, 0], 60),  # out of plane: the reference's 32-gon discs lie up to 0.24 px inside
    ([15, 15], [0, 9], 30),
])
@pytest.mark.parametrize("pixel_size", [0.25e-3, 0.4e-3])
def test_the_two_renderers_draw_the_same_silhouette(table, ids, steps, limit, pixel_size):
    offsets = np.radians(np.random.default_rng(len(ids)).uniform(-2.5, 2.5, len(ids)))
    reference, pose, _ = render_chain(ids, steps, table, pixel_size, offsets=offsets, angle=1.0, mirrored=True)
    capsule, capsule_pose, _ = capsule_chain(ids, steps, table, pixel_size, offsets=offsets, frame=(pose, reference.shape))
    assert capsule_pose == pose
    differ = to_binary(reference) != to_binary(capsule)
    assert differ.sum() <= limit, f"{differ.sum()} of {to_binary(capsule).astype(bool).sum()} pixels differ"


def test_its_images_are_estimated_like_the_references(table):
    from estimation.estimate import estimate_chain

    ids = [57, 36, 15]
    coverage, pose, theta = capsule_chain(ids, None, table, PIXEL, offsets=np.radians([1.0, -2.0, 1.5]), angle=2.5)
    result = estimate_chain(to_binary(coverage), make_chain(ids), PIXEL, pose, table=table)
    assert result.as_built, result.message
    assert np.all(np.abs(np.degrees(result.theta - theta)) < 0.5)

"""The reference renderer against closed forms (it is the ground truth of the estimation tests)."""
import math

import numpy as np
import pytest

from estimation.render import blurred, framing, occluded, render_silhouette, with_pixel_noise
from estimation.view import ImagePose
from planner.geometry import PAPER_GEOMETRY

pytestmark = pytest.mark.fast

PIXEL = 0.25e-3
R, CAP = PAPER_GEOMETRY.radius, PAPER_GEOMETRY.cap_length


def test_a_straight_block_is_a_rectangle_of_the_tube_width_and_the_block_length():
    pose = ImagePose(0.05, 0.01, math.pi / 2)  # grows down from (50, 10) mm
    coverage = render_silhouette([0.0], [15e-3], [0.0], pose, PIXEL, (200, 400))
    rows = np.flatnonzero(coverage.max(axis=1) > 0)
    columns = np.flatnonzero(coverage.max(axis=0) > 0)
    assert (rows[0], rows[-1] + 1) == (40, 120)  # 10 mm to 30 mm: cap + 15 mm + cap
    assert (columns[0], columns[-1] + 1) == (150, 250)  # 25 mm wide, centred on x = 50 mm
    assert coverage.sum() * PIXEL**2 == pytest.approx(25e-3 * 20e-3, rel=1e-9)


def _block_end(theta, length):
    """(x, z) of a block's end in its start frame: cap, chord of the arc, cap along the end tangent."""
    half = theta / 2
    chord = length * math.sin(half) / half
    return np.array([chord * math.sin(half) + CAP * math.sin(theta), CAP + chord * math.cos(half) + CAP * math.cos(theta)])


@pytest.mark.parametrize("degrees", [5.0, 32.0, 44.0])
def test_a_bent_block_has_the_area_of_its_annulus_sector_and_caps(degrees):
    theta, length = math.radians(degrees), 15e-3
    coverage = render_silhouette([theta], [length], [0.0], ImagePose(0.06, 0.03, 1.0), PIXEL, (300, 400))
    # sector between radii L/theta -+ r: theta/2 ((R + r)^2 - (R - r)^2) = 2 L r; each cap a 2r x cap rectangle
    expected = 2 * length * R + 2 * (2 * R * CAP)
    assert coverage.sum() * PIXEL**2 == pytest.approx(expected, abs=2 * PIXEL**2)


def test_the_bend_goes_to_the_chains_plus_x_and_mirrors_with_the_pose():
    theta, length = math.radians(40), 15e-3
    pose = ImagePose(0.05, 0.01, math.pi / 2)  # +x is image -x (left)
    left = render_silhouette([theta], [length], [0.0], pose, PIXEL, (200, 400))
    right = render_silhouette([theta], [length], [0.0], ImagePose(0.05, 0.01, math.pi / 2, True), PIXEL, (200, 400))
    assert _centroid(left)[0] < 0.05 < _centroid(right)[0]
    np.testing.assert_allclose(left[:, ::-1], right, atol=1e-12)


def _centroid(coverage):
    rows, columns = np.indices(coverage.shape)
    return np.array([(coverage * (columns + 0.5)).sum(), (coverage * (rows + 0.5)).sum()]) / coverage.sum() * PIXEL


def test_a_worm_is_point_symmetric_about_its_first_block_end():
    theta, length = math.radians(30), 15e-3
    pose = ImagePose(0.05, 0.01, math.pi / 2)
    worm = render_silhouette([theta, theta], [length, length], [0.0, math.pi], pose, PIXEL, (260, 400))
    middle = pose.to_image(_block_end(theta, length))
    np.testing.assert_allclose(_centroid(worm), middle, atol=0.05 * PIXEL)
    # the end of the worm lies on the line through the base and the middle, twice as far
    rows, columns = np.nonzero(worm > 0.5)
    assert abs((rows.max() + 1) * PIXEL - (0.01 + 2 * (middle[1] - 0.01))) < PIXEL


def test_a_block_bent_toward_the_camera_projects_straight_with_its_tilted_end_disc():
    theta, length = math.radians(40), 15e-3
    pose = ImagePose(0.05, 0.01, math.pi / 2)
    toward = render_silhouette([theta], [length], [math.pi / 2], pose, PIXEL, (260, 400))
    rows, columns = np.nonzero(toward > 0.5)
    # straight band 2r wide; it reaches the end's z plus r sin(theta) (the rim of the tilted end disc)
    assert (columns.max() + 1 - columns.min()) * PIXEL == pytest.approx(2 * R, abs=PIXEL)
    reach = _block_end(theta, length)[1] + R * math.sin(theta)
    assert (rows.max() + 1) * PIXEL - 0.01 == pytest.approx(reach, abs=PIXEL)


def test_framing_keeps_the_whole_chain_inside_with_the_margin():
    theta, length, phi = np.radians([30, 40, 20]), np.array([15e-3, 10e-3, 12.5e-3]), np.zeros(3)
    pose, shape = framing(theta, length, phi, PIXEL, angle=1.0, margin=5e-3)
    coverage = render_silhouette(theta, length, phi, pose, PIXEL, shape)
    margin = int(5e-3 / PIXEL) - 1
    assert coverage[:margin].max() == 0 and coverage[-margin:].max() == 0
    assert coverage[:, :margin].max() == 0 and coverage[:, -margin:].max() == 0
    assert coverage.max() == 1.0


def test_image_faults():
    rng = np.random.default_rng(0)
    image = np.zeros((50, 50), dtype=np.uint8)
    image[10:40, 10:40] = 255
    noisy = with_pixel_noise(image, 0.1, rng)
    assert 0.07 < np.mean(noisy != image) < 0.13
    hidden = occluded(image, (40.0, 40.0), 10.0)
    assert hidden[35, 35] == 0 and hidden[15, 15] == 255
    soft = blurred(image / 255.0, 2.0)
    assert 0.4 < soft[25, 10] < 0.6

"""The estimator's forward model (planner kinematics) against the independent reference renderer."""
import math

import numpy as np
import pytest

from estimation.outline import outline_layout, outline_points, planar_centreline, start_frame, visible
from estimation.render import render_silhouette, to_binary, to_grey
from estimation.silhouette import silhouette_from_image
from estimation.view import ImagePose
from planner.kinematics import planar_chain

from estimation_scenes import PIXEL

pytestmark = pytest.mark.fast

CHAINS = {
    "arc": (np.radians([32, 20, 40]), [15e-3, 10e-3, 12.5e-3], [0, 0, 0]),
    "worm": (np.radians([32, 20, 40]), [15e-3, 10e-3, 12.5e-3], [0, math.pi, 0]),
    "helix step": (np.radians([32, 20, 40]), [15e-3, 10e-3, 12.5e-3], [0, math.pi / 6, 0]),
    "toward camera": (np.radians([25, 35]), [15e-3, 15e-3], [0, math.pi / 2]),
}


@pytest.mark.parametrize("name", CHAINS)
def test_model_outline_lies_on_the_rendered_outline(name):
    theta, length, phi = CHAINS[name]
    pose = ImagePose(0.06, 0.01, math.pi / 2)
    coverage = render_silhouette(theta, length, phi, pose, PIXEL, (320, 480))
    points = pose.to_image(outline_points(outline_layout(length, phi, 0.5e-3), theta))
    for image, threshold, rms_limit in ((to_binary(coverage), None, 0.3), (to_grey(coverage), 127.5, 0.12)):
        distance, _ = silhouette_from_image(image, PIXEL, threshold).signed_distance(points)
        assert np.sqrt(np.mean(distance**2)) < rms_limit * PIXEL
        assert np.abs(distance).max() < 1.2 * PIXEL
        assert abs(distance.mean()) < 0.1 * PIXEL


@pytest.mark.parametrize("name", CHAINS)
def test_later_blocks_placed_at_their_start_frame_match_the_whole_chain(name):
    theta, _, phi = CHAINS[name]
    length, phi = np.array([10e-3, 15e-3, 12.5e-3][: len(theta)]), np.array(phi, dtype=float)
    whole = outline_layout(length, phi, 0.75e-3)
    everything = outline_points(whole, theta)
    part = outline_layout(length[1:], phi[1:], 0.75e-3)  # the longest block is in both: same sampling
    tail = outline_points(part, theta[1:], start_frame(theta, length, phi, 1))
    first = whole.samples_per_block
    np.testing.assert_allclose(tail[: part.centreline_samples], everything[first : whole.centreline_samples], atol=1e-12)


def test_a_chain_touching_itself_hides_the_overlapping_outline():
    # a tight curl, then a wider one: the second turn runs across the first (a constant curvature would
    # only retrace itself)
    theta = np.radians([45] * 6 + [25] * 6)
    layout = outline_layout(np.full(12, 10e-3), np.zeros(12), 0.5e-3)
    shown = visible(layout, theta)
    assert 0 < np.count_nonzero(~shown) < 0.3 * shown.size
    assert visible(layout, theta / 4).all()


def test_faces_close_the_outline_and_blocks_are_labelled():
    layout = outline_layout([15e-3, 10e-3], [0.0, 0.0], 0.5e-3)
    points = outline_points(layout, np.zeros(2))
    base, tip = layout.polylines[2], layout.polylines[3]
    np.testing.assert_allclose(points[base][:, 1], 0.0, atol=1e-15)  # the base face spans x = -r..r at z = 0
    np.testing.assert_allclose(points[base][[0, -1], 0], [-12.5e-3, 12.5e-3])
    np.testing.assert_allclose(points[tip][:, 1], 15e-3 + 10e-3 + 4 * 2.5e-3)
    assert set(layout.block[base]) == {0} and set(layout.block[tip]) == {1}
    assert np.all(np.diff(layout.block[layout.polylines[0]]) >= 0)


@pytest.mark.parametrize("phi", [[0, 0, 0], [0, math.pi, 0], [math.pi, 0, math.pi]])
def test_the_closed_form_planar_centreline_is_the_kinematics(phi):
    length = [15e-3, 10e-3, 12.5e-3]
    layout = outline_layout(length, phi, 0.75e-3)
    theta = np.random.default_rng(2).uniform(-0.8, 0.8, (4, 3))
    theta[0] = [0.0, 1e-9, 0.5]  # straight and nearly straight blocks
    points, heading = planar_centreline(layout, theta)
    shape = planar_chain(theta, length, phi, samples_per_block=layout.samples_per_block)
    np.testing.assert_allclose(points, shape.points, atol=1e-12)
    np.testing.assert_allclose(heading, shape.headings, atol=1e-12)

"""Image checks: every bad image gets an error naming its problem; distances to the outline."""
import math

import numpy as np
import pytest
from PIL import Image

from estimation.render import render_chain, to_binary
from estimation.silhouette import MAX_IMAGE_PIXELS, check_base, read_image, silhouette_from_image
from estimation.view import ImagePose

from estimation_scenes import PIXEL

pytestmark = pytest.mark.fast

R, CAP = 12.5e-3, 2.5e-3


def rectangle(rows=80, columns=100):
    image = np.zeros((rows, columns), dtype=np.uint8)
    image[20:60, 30:70] = 255
    return image


def test_signed_distance_is_positive_outside_and_exact_on_straight_edges():
    silhouette = silhouette_from_image(rectangle(), 1e-3)
    # the square spans x 30..70 mm, y 20..60 mm (pixel edges)
    points = np.array([[0.050, 0.015], [0.050, 0.025], [0.075, 0.040], [0.065, 0.040]])
    distance, normals = silhouette.signed_distance(points)
    np.testing.assert_allclose(distance, [5e-3, -5e-3, 5e-3, -5e-3], atol=1e-9)
    np.testing.assert_allclose(normals, [[0, -1], [0, -1], [1, 0], [1, 0]], atol=1e-9)
    far, _ = silhouette.signed_distance(np.array([[0.0, 0.0]]), limit=2e-3)
    assert far[0] == 2e-3
    assert silhouette.coarse_distance(points) == pytest.approx([5e-3, -5e-3, 5e-3, -5e-3], abs=2e-3)


@pytest.mark.parametrize(
    "image, problem",
    [
        (np.zeros((50, 50), np.uint8), "empty"),
        (np.pad(np.full((10, 10), 255, np.uint8), ((0, 40), (20, 20))), "touches the image border"),
        (np.hstack([rectangle(), rectangle()]), "2 objects"),
        (np.arange(100 * 80, dtype=np.uint16).reshape(80, 100), "not binary"),
        (np.zeros((4, 50), np.uint8), "at least 8"),
        (np.zeros((3, 3, 3), np.uint8), "2D"),
        (np.full((20, 20), np.nan), "non-finite"),
    ],
)
def test_bad_images_are_refused_naming_the_problem(image, problem):
    with pytest.raises(ValueError, match=problem):
        silhouette_from_image(image, PIXEL)


def test_bad_pixel_sizes_and_files(tmp_path):
    for size in (0.0, -1e-3, math.nan, "0.25"):
        with pytest.raises(ValueError, match="pixel_size"):
            silhouette_from_image(rectangle(), size)
    with pytest.raises(ValueError, match="cannot read"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "junk.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="cannot read"):
        read_image(tmp_path / "junk.png")


def test_oversized_images_are_refused_before_decoding(tmp_path):
    side = int(math.sqrt(MAX_IMAGE_PIXELS)) + 1
    Image.new("1", (side, side)).save(tmp_path / "huge.png")  # compresses to a few kB
    with pytest.raises(ValueError, match="more than the limit"):
        read_image(tmp_path / "huge.png")


def test_grey_images_need_a_threshold_and_colour_files_load(tmp_path):
    grey = rectangle() // 2 + 10
    grey[30, 40] = 99  # a third level
    with pytest.raises(ValueError, match="threshold"):
        silhouette_from_image(grey, PIXEL)
    assert silhouette_from_image(grey, PIXEL, threshold=60).mask.sum() == 40 * 40
    Image.fromarray(np.stack([rectangle()] * 3, axis=-1)).save(tmp_path / "colour.png")
    assert silhouette_from_image(tmp_path / "colour.png", PIXEL).mask.sum() == 40 * 40


def test_specks_do_not_add_outline():
    image = rectangle()
    image[5, 5] = 255
    clean = silhouette_from_image(rectangle(), 1e-3)
    speckled = silhouette_from_image(image, 1e-3)
    assert len(speckled.outline) == len(clean.outline)


def test_the_base_must_start_the_chain(table):
    coverage, pose, _ = render_chain([15, 15], [0, 0], table, PIXEL, angle=1.2)
    silhouette = silhouette_from_image(to_binary(coverage), PIXEL)
    check_base(silhouette, pose, R, CAP)
    wrong = {
        "moved along the chain": ImagePose(*pose.to_image([0.0, 0.02]), pose.angle, pose.mirrored),
        "pointing away": ImagePose(pose.x, pose.y, pose.angle + math.pi, pose.mirrored),
        "at the tip": ImagePose(*pose.to_image([0.0, 0.05]), pose.angle, pose.mirrored),
    }
    for name, bad in wrong.items():
        with pytest.raises(ValueError, match="does not start at the given base"):
            check_base(silhouette, bad, R, CAP)
    with pytest.raises(ValueError, match="outside the image"):
        check_base(silhouette, ImagePose(-0.01, pose.y, pose.angle), R, CAP)

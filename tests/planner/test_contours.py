"""Object image pipeline: cleaning, error paths, left/right split, scale and frame."""
import numpy as np
import pytest
from PIL import Image

from planner.contours import OBJECTS_CATALOG, clean_mask, extract_contours, load_catalog_object, load_mask

pytestmark = pytest.mark.fast


def rectangle(rows=40, columns=50, top=10, bottom=30, left=15, right=27):
    mask = np.zeros((rows, columns), dtype=bool)
    mask[top:bottom, left:right] = True
    return mask


def test_rectangle_is_split_into_two_straight_sides_at_scale():
    contours = extract_contours(rectangle(), pixel_size=0.5e-3)
    assert contours.height == pytest.approx(20 * 0.5e-3)
    assert contours.width == pytest.approx(12 * 0.5e-3)
    # origin at the top-centre, z up: the top cut is at z = 0, the bottom cut at z = -height.
    assert contours.top[1] == pytest.approx(0.0)
    assert contours.bottom[1] == pytest.approx(-10e-3)
    sides = {"left": (contours.left, -3e-3), "right": (contours.right, 3e-3)}
    for name, (side, x) in sides.items():
        assert np.all(np.diff(side[:, 1]) <= 0), f"{name} contour is not ordered top to bottom"
        vertical = side[np.isclose(side[:, 0], x)]
        # one vertex per pixel row, at the row centres: z = -0.25 mm ... -9.75 mm
        np.testing.assert_allclose(vertical[:, 1], -0.25e-3 - 0.5e-3 * np.arange(20), err_msg=name)
    assert np.all(contours.left[:, 0] <= 0) and np.all(contours.right[:, 0] >= 0)


def test_pixel_size_scales_the_contours_linearly():
    small = extract_contours(rectangle(), pixel_size=1e-4)
    large = extract_contours(rectangle(), pixel_size=3e-4)
    np.testing.assert_allclose(large.left, 3 * small.left)
    np.testing.assert_allclose(large.right, 3 * small.right)


def on_object(contours, points) -> np.ndarray:
    """Which points (..., 2) = (x, z) [m] of the object frame fall on an object pixel of the cleaned mask."""
    column0, row0 = contours.origin_pixel
    column = np.floor(points[..., 0] / contours.pixel_size + column0).astype(int)
    row = np.floor(row0 - points[..., 1] / contours.pixel_size).astype(int)
    rows, columns = contours.mask.shape
    inside = (column >= 0) & (column < columns) & (row >= 0) & (row < rows)
    return np.where(inside, contours.mask[np.clip(row, 0, rows - 1), np.clip(column, 0, columns - 1)], False)


def test_the_object_frame_has_its_origin_at_the_top_centre_x_right_z_up():
    contours = extract_contours(rectangle(), pixel_size=1e-3)
    points = np.array([[0.0, -5e-3], [5.9e-3, -0.1e-3], [6.1e-3, -5e-3], [0.0, 0.1e-3], [0.0, -19.9e-3],
                       [0.0, -20.1e-3], [1.0, 1.0]])
    np.testing.assert_array_equal(on_object(contours, points), [True, True, False, False, True, False, False])


def test_specks_are_removed_and_holes_filled():
    mask = rectangle()
    mask[2, 2] = True  # a speck
    mask[18:22, 19:23] = False  # a hole
    cleaned = clean_mask(mask)
    np.testing.assert_array_equal(cleaned, rectangle())


def test_asymmetric_sides_are_not_mirror_images():
    contours = extract_contours(load_mask(OBJECTS_CATALOG.parent / "asymmetric.png"), 0.25e-3)
    depth = np.linspace(-80e-3, -10e-3, 15)
    left = np.interp(depth, contours.left[::-1, 1], contours.left[::-1, 0])
    right = np.interp(depth, contours.right[::-1, 1], contours.right[::-1, 0])
    assert np.max(np.abs(left + right)) > 3e-3


@pytest.mark.parametrize("name", ["asymmetric", "strawberry", "gingerbread"])
def test_sample_objects_load_with_sensible_sizes(name):
    contours = load_catalog_object(name)
    assert 0.03 < contours.height <= 0.095
    assert 0.005 < contours.width < 0.05
    # the contours lie on the outline: just inside is object, just outside is not
    for side, outward in ((contours.left, -1), (contours.right, 1)):
        middle = side[len(side) // 4 : 3 * len(side) // 4]
        step = np.array([outward * 2 * contours.pixel_size, 0.0])
        assert on_object(contours, middle - step).mean() > 0.9
        assert not on_object(contours, middle + step).any()


def test_png_and_pgm_files_load_and_grey_images_need_a_threshold(tmp_path):
    mask = rectangle()
    Image.fromarray(mask.astype(np.uint8) * 255).save(tmp_path / "object.png")
    Image.fromarray(mask.astype(np.uint8) * 200).save(tmp_path / "object.pgm")
    np.testing.assert_array_equal(load_mask(tmp_path / "object.png"), mask)
    np.testing.assert_array_equal(load_mask(tmp_path / "object.pgm"), mask)
    grey = mask * 180.0 + np.linspace(0, 40, mask.shape[1])
    with pytest.raises(ValueError, match="not binary.*threshold"):
        load_mask(grey)
    np.testing.assert_array_equal(load_mask(grey, threshold=100), mask)
    Image.fromarray(np.dstack([mask * 255] * 3).astype(np.uint8)).save(tmp_path / "rgb.png")
    np.testing.assert_array_equal(load_mask(tmp_path / "rgb.png"), mask)


@pytest.mark.parametrize(
    ("mask", "message"),
    [
        (np.zeros((20, 20), dtype=bool), "empty"),
        (rectangle() | rectangle(top=2, bottom=8, left=2, right=40), "2 objects"),
        (rectangle(top=0), "touches the image border"),
        (rectangle(right=50), "touches the image border"),
        (rectangle(top=10, bottom=11, left=10, right=11), "object is only 1 x 1 pixels; it needs at least 8"),
        (rectangle(top=10, bottom=30, left=10, right=13), "object is only 3 x 20 pixels"),
    ],
)
def test_bad_images_are_named(mask, message):
    with pytest.raises(ValueError, match=message):
        extract_contours(mask, 1e-3)


def test_bad_arguments_are_named(tmp_path):
    with pytest.raises(ValueError, match="pixel_size"):
        extract_contours(rectangle(), 0.0)
    for absurd in (1e300, 1e-300):  # found by fuzzing planner/design_fingers: it never answered
        with pytest.raises(ValueError, match=r"pixel_size must be a positive number of m/pixel in 1e-06..0.01, got"):
            extract_contours(rectangle(), absurd)
    with pytest.raises(ValueError, match="cannot read object image"):
        load_mask(tmp_path / "missing.png")
    with pytest.raises(ValueError, match="2D"):
        load_mask(np.zeros(5))
    with pytest.raises(ValueError, match="not in"):
        load_catalog_object("teapot")


def test_an_oversized_image_is_refused_before_its_pixels_are_decoded(tmp_path, monkeypatch):
    path = tmp_path / "huge.png"
    Image.new("1", (8000, 8000)).save(path)  # 64 megapixels, a few kB as a PNG
    decoded = []
    monkeypatch.setattr(Image.Image, "load", lambda image: decoded.append(image))
    with pytest.raises(ValueError, match=r"huge.png is 8000 x 8000 pixels, more than the 4 megapixels accepted"):
        load_mask(path)
    assert decoded == []
    with pytest.raises(ValueError, match=r"object image is 3000 x 2000 pixels"):
        load_mask(np.zeros((2000, 3000), dtype=np.uint8))


def test_a_path_that_is_not_a_regular_file_is_refused(tmp_path):
    with pytest.raises(ValueError, match="cannot read object image .*: not a regular file"):
        load_mask(tmp_path)

"""Images named by users and clients: a header claiming a decompression bomb's size, a FIFO or junk is one
ValueError line, wherever images are read (planner.contours, estimation.silhouette)."""
import os

import pytest
from crafted_images import png_header
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.silhouette import read_image
from planner.contours import load_mask
from planner.image_file import open_image

pytestmark = pytest.mark.fast


@pytest.mark.parametrize("read, what", [(load_mask, "object image"), (read_image, "image")])
@pytest.mark.parametrize("side", [30_000, 10_000])  # 900 MP (Pillow's error), 100 MP (Pillow's warning)
def test_a_header_claiming_a_bomb_is_refused_in_one_line(tmp_path, read, what, side):
    path = tmp_path / "bomb.png"
    path.write_bytes(png_header(side, side))
    with pytest.raises(ValueError, match=rf"^cannot read {what} .*bomb.png: its header claims more than \d+ "
                                         "pixels, a decompression bomb's size$"):
        read(path)


@pytest.mark.parametrize("read", [load_mask, read_image])
def test_a_fifo_is_refused_without_blocking(tmp_path, read):
    fifo = tmp_path / "camera.png"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match=r"camera.png: not a regular file"):
        read(fifo)


@settings(max_examples=100, deadline=None)
@given(width=st.integers(0, 2**31 - 1), height=st.integers(0, 2**31 - 1), tail=st.binary(max_size=64))
def test_any_png_header_opens_or_is_refused_in_one_line(tmp_path_factory, width, height, tail):
    path = tmp_path_factory.mktemp("headers") / "fuzzed.png"
    path.write_bytes(png_header(width, height)[:-12] + tail)
    try:
        with open_image(path) as image:
            assert image.width * image.height <= 2 * 89_478_485
    except ValueError as error:
        assert str(error).startswith(f"cannot read image {path}: ") and "\n" not in str(error)

"""Opening an image file named by a user or a client (no ROS).

Pillow decodes the pixels only when they are used, and the width and height are in the header: a caller
checks ``image.width * image.height`` against its own limit before touching the pixels. Pillow's own guard
against decompression bombs raises DecompressionBombError (not an OSError) from ``Image.open`` for a header
beyond 179 megapixels and warns beyond 89: both become a one-line ValueError here, as does any OSError (no
such file, not an image, a truncated one). Only regular files are opened (planner.regular_file).
"""
from __future__ import annotations

import contextlib
import os
import warnings
from pathlib import Path

from PIL import Image

from .regular_file import NotARegularFileError, open_regular


@contextlib.contextmanager
def open_image(path: str | Path, what: str = "image"):
    """A Pillow image of the regular file ``path`` (pixels not decoded yet); ValueError ("cannot read <what>
    <path>: ...") when it is not one or claims a decompression bomb's size."""
    refusal = f"cannot read {what} {path}"
    try:
        with os.fdopen(open_regular(path), "rb") as stream, warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            try:
                image = Image.open(stream)
            except (Image.DecompressionBombError, Image.DecompressionBombWarning):
                raise ValueError(f"{refusal}: its header claims more than {Image.MAX_IMAGE_PIXELS} pixels, "
                                 "a decompression bomb's size") from None
            with image:
                yield image
    except NotARegularFileError:
        raise ValueError(f"{refusal}: not a regular file") from None
    except OSError as error:  # no such file, no permission, not an image, a truncated image
        raise ValueError(f"{refusal}: {error.strerror or error}") from None

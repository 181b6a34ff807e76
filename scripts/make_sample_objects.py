"""Write the sample object images of config/objects/ (deterministic; run from the repo root).

Each object is a binary side view (object white on black, PNG) drawn from a profile: the left and right
edge x [mm] as functions of the depth d [mm] below the object's top. Rows are pixel centres.
    scripts/with_env.sh python scripts/make_sample_objects.py
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from PIL import Image

PIXEL_SIZE = 0.25e-3  # [m / pixel]
MARGIN_MM = 8.0
OUT = Path(__file__).resolve().parent.parent / "config" / "objects"


def _bump(d, centre, width):
    return np.exp(-(((d - centre) / width) ** 2))


def _rounded_ends(d, height, power=6):
    """1 in the middle, falling to 0 at both ends: rounds the top and bottom of a profile."""
    return np.sqrt(np.clip(1.0 - np.abs(2.0 * d / height - 1.0) ** power, 0.0, None))


def asymmetric(d):
    """The paper's complex object (Figure 5B): 90 mm tall, two different sides, concave and convex."""
    ends = _rounded_ends(d, 90.0)
    left = -(15.0 - 6.0 * _bump(d, 32.0, 9.0) + 4.0 * _bump(d, 66.0, 8.0)) * ends
    right = (13.0 + 5.0 * _bump(d, 22.0, 11.0) - 5.5 * _bump(d, 55.0, 8.0) + 2.0 * _bump(d, 78.0, 6.0)) * ends
    return left, right, 90.0


def strawberry(d):
    """A strawberry seen from the side, tip down: 45 mm tall, 34 mm at its widest, slightly lopsided."""
    u = np.clip(d / 45.0, 0.0, 1.0)
    widest = 0.5 / 1.3  # where u**0.5 * (1 - u)**0.8 peaks
    half = 17.0 * (u / widest) ** 0.5 * ((1.0 - u) / (1.0 - widest)) ** 0.8
    lean = 1.5 * u  # the tip leans a little to the right
    return lean - half, lean + half * (1.0 + 0.06 * np.sin(np.pi * u)), 45.0


def gingerbread(d):
    """A gingerbread wall held upright, seen edge-on: an almost flat slab 80 mm tall, ~10 mm thick."""
    ends = _rounded_ends(d, 80.0, power=16)
    left = -(5.0 + 0.5 * np.sin(d / 6.0) + 0.3 * np.sin(d / 2.3 + 1.0)) * ends
    right = (5.0 + 0.4 * np.sin(d / 7.5 + 2.0) + 0.3 * np.sin(d / 3.1)) * ends
    return left, right, 80.0


OBJECTS = {
    "asymmetric": (asymmetric, "complex object with concave and convex edges and two different sides"),
    "strawberry": (strawberry, "strawberry, tip down"),
    "gingerbread": (gingerbread, "gingerbread wall, an almost flat lumpy slab"),
}


def render(profile) -> np.ndarray:
    """Boolean mask of a profile with MARGIN_MM of background all round."""
    mm = PIXEL_SIZE * 1e3
    _, _, height = profile(np.array([0.0]))
    depth = np.arange(-MARGIN_MM, height + MARGIN_MM, mm) + 0.5 * mm
    left, right, _ = profile(np.clip(depth, 0.0, height))
    inside_depth = (depth >= 0.0) & (depth <= height)
    span = np.max(np.abs(np.concatenate([left, right])))
    x = np.arange(-span - MARGIN_MM, span + MARGIN_MM, mm) + 0.5 * mm
    return inside_depth[:, None] & (x[None, :] >= left[:, None]) & (x[None, :] <= right[:, None])


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    catalog = {}
    for name, (profile, description) in OBJECTS.items():
        Image.fromarray(render(profile).astype(np.uint8) * 255).save(OUT / f"{name}.png", optimize=True)
        catalog[name] = {"file": f"{name}.png", "pixel_size_m": PIXEL_SIZE, "description": description}
        print(f"wrote {OUT / name}.png")
    header = "# Sample objects: binary side views (object white), made by scripts/make_sample_objects.py.\n"
    (OUT / "objects.yaml").write_text(header + yaml.safe_dump(catalog, sort_keys=False))


if __name__ == "__main__":
    main()

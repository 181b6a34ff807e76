"""The finger search's lookahead fields against the fingers they bound: at grid nodes in the frame of a
block position's start, ``body`` and ``tip`` are lower bounds on the distance to every continuation's
centerline samples and tip periphery point, ``cover`` an upper bound on the distance to every
continuation's continuous centerline (a wrong cover would prune collision-free fingers)."""
import numpy as np
import pytest

from planner.clearance import block_point
from planner.kinematics import BLOCK_RADIUS, CAP_LENGTH
from planner.optimize import design_space
from planner.optimize.lookahead import COVER_MARGIN, block_shapes, lookahead_fields
from planner.table import load_table

pytestmark = pytest.mark.fast

SHELF = {i: 3 for i in (2, 8, 14, 19, 27, 33, 40, 45, 61, 64, 71, 78)}
CONTINUOUS_STEP = 5e-5  # [m] arc-length step of the reference centerline


def continuation(shapes, path):
    """Samples, tip periphery point and dense continuous centerline of blocks ``path`` from the origin."""
    x = z = heading = 0.0
    samples, dense = [], []
    for s in path:
        cos, sin = np.cos(heading), np.sin(heading)
        place = lambda p: (x + p[0] * cos + p[1] * sin, z - p[0] * sin + p[1] * cos)  # noqa: E731
        samples += [place(p) for p in shapes.samples[s]]
        total = 2 * CAP_LENGTH + shapes.length[s]
        dense += [place(block_point(shapes.theta[s], shapes.length[s], CAP_LENGTH, t))
                  for t in np.arange(0.0, total + CONTINUOUS_STEP, CONTINUOUS_STEP).clip(max=total)]
        x, z = place(shapes.ends[s, :2])
        heading += shapes.ends[s, 2]
    tip = (x + BLOCK_RADIUS * np.cos(heading), z - BLOCK_RADIUS * np.sin(heading))
    return np.array(samples), np.array(tip), np.array(dense)


@pytest.mark.parametrize("blocks, stiff", [(2, 1), (3, 1)])
def test_fields_bound_every_continuation(blocks, stiff):
    space = design_space(load_table(), blocks, stiff_positions=range(stiff), inventory=SHELF)
    shapes = block_shapes(space, CAP_LENGTH)
    fields = lookahead_fields(shapes, space, BLOCK_RADIUS, 5e-4, 2e-4)
    rng = np.random.default_rng(blocks)
    cap = BLOCK_RADIUS + COVER_MARGIN
    covered = 0
    for depth in range(blocks):
        offset, rows, cols, x0, z0, _, spacing = fields.layout[depth]
        offset, rows, cols, count = int(offset), int(rows), int(cols), len(space.choices[depth])
        for _ in range(60):
            k = int(rng.integers(count))
            path = [space.choices[depth][k]] + [int(rng.choice(c)) for c in space.choices[depth + 1:]]
            samples, tip, dense = continuation(shapes, path)
            # nodes near the continuation, where the bounds matter
            centre = dense[rng.integers(len(dense))] + rng.normal(0.0, 0.01, 2)
            a, b = int(np.clip(round((centre[1] - z0) / spacing), 0, rows - 1)), \
                int(np.clip(round((centre[0] - x0) / spacing), 0, cols - 1))
            node = np.array([x0 + b * spacing, z0 + a * spacing])
            index = offset + (a * cols + b) * count + k
            assert np.linalg.norm(samples - node, axis=1).min() >= fields.body[index] - 1e-9
            assert np.linalg.norm(tip - node) >= fields.tip[index] - 1e-9
            nearest = min(np.linalg.norm(dense - node, axis=1).min(), cap)
            assert nearest <= fields.cover[index] + CONTINUOUS_STEP, (depth, path, node)
            covered += bool(fields.cover[index] < cap)
    assert covered > 20, "the test never met an informative cover"

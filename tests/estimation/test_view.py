"""The image frame and the chain base's pose in it."""
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from estimation.view import ImagePose

pytestmark = pytest.mark.fast


def test_a_chain_growing_down_bends_to_the_left_unless_mirrored():
    # camera looking along the chain's +y: image x right, y down; the chain grows down (+z -> image +y)
    pose = ImagePose(0.02, 0.01, math.pi / 2)
    np.testing.assert_allclose(pose.to_image([0.0, 0.005]), [0.02, 0.015], atol=1e-15)
    np.testing.assert_allclose(pose.to_image([0.003, 0.0]), [0.017, 0.01], atol=1e-15)
    mirrored = ImagePose(0.02, 0.01, math.pi / 2, mirrored=True)
    np.testing.assert_allclose(mirrored.to_image([0.003, 0.0]), [0.023, 0.01], atol=1e-15)


def test_shift_and_turn_move_the_base():
    pose = ImagePose(0.0, 0.0, 0.0)  # grows along image +x, bends toward image +y
    np.testing.assert_allclose(pose.to_image([0.0, 1.0], shift=(0.1, 0.2), turn=math.pi / 2), [0.1, 1.2], atol=1e-12)
    np.testing.assert_allclose(pose.corrected((0.1, 0.2), math.pi / 2).to_image([0.0, 1.0]), [0.1, 1.2], atol=1e-12)


@given(
    st.floats(-1, 1), st.floats(-1, 1), st.floats(-10, 10), st.booleans(),
    st.lists(st.floats(-0.5, 0.5), min_size=2, max_size=2),
)
def test_to_chain_inverts_to_image(x, y, angle, mirrored, point):
    pose = ImagePose(x, y, angle, mirrored)
    np.testing.assert_allclose(pose.to_chain(pose.to_image(point)), point, atol=1e-12)


@pytest.mark.parametrize("bad", [dict(x=math.nan), dict(angle=math.inf), dict(y="0"), dict(mirrored=1)])
def test_bad_poses_are_refused_naming_the_field(bad):
    values = dict(x=0.0, y=0.0, angle=0.0, mirrored=False) | bad
    with pytest.raises(ValueError, match=next(iter(bad))):
        ImagePose(**values)

"""TF in tests: compose a list of TransformStamped to one root frame, as a tf2 listener does."""
import numpy as np
from scipy.spatial.transform import Rotation


def matrix(transform) -> np.ndarray:
    t, q = transform.transform.translation, transform.transform.rotation
    frame = np.eye(4)
    frame[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    frame[:3, 3] = [t.x, t.y, t.z]
    return frame


def in_root(transforms, root: str) -> dict[str, np.ndarray]:
    """Every child frame in ``root``, composed along its parents as a TF listener does."""
    parents = {t.child_frame_id: t for t in transforms}
    assert len(parents) == len(transforms), "a frame has two parents"

    def compose(frame: str) -> np.ndarray:
        if frame == root:
            return np.eye(4)
        link = parents[frame]
        return compose(link.header.frame_id) @ matrix(link)

    return {frame: compose(frame) for frame in parents}

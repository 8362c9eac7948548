"""IPPE in numba against OpenCV's, and exact on exact points."""

import cv2
import numpy as np

from tdacm.vision import PAPER_MARKER, PAPER_PATTERN
from tdacm.vision.ippe import DEPTHS_OK, canonical_frame, ippe_poses, point_depths


def _views(target, rng, count, noise_px):
    obj = target.feature_points
    for _ in range(count):
        r = cv2.Rodrigues(rng.normal(0, 0.5, 3))[0]
        t = np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), rng.uniform(0.5, 4)])
        pc = obj @ r.T + t
        if np.any(pc[:, 2] <= 0.05):
            continue
        yield r, t, pc[:, :2] / pc[:, 2:3] + rng.normal(0, noise_px / 886.8, (4, 2))


def test_both_poses_equal_opencvs_on_noisy_points():
    """The two poses of ``cv2.solvePnPGeneric(..., SOLVEPNP_IPPE)``, in its order, to 1e-9
    (measured 5e-12) for 3 px of noise on both targets."""
    rng = np.random.default_rng(4)
    for target in (PAPER_MARKER, PAPER_PATTERN):
        obj = target.feature_points
        o2, gc = canonical_frame(obj)
        for _, _, xy in _views(target, rng, 300, 3.0):
            ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                obj, xy.reshape(-1, 1, 2), np.eye(3), None, flags=cv2.SOLVEPNP_IPPE
            )
            rots, trans, err = np.empty((2, 3, 3)), np.empty((2, 3)), np.empty(2)
            assert ok and ippe_poses(o2, np.ascontiguousarray(xy), rots, trans, err)
            for s in range(2):
                r = rots[s] @ gc[:3, :3].T
                t = trans[s] - r @ gc[:3, 3]
                np.testing.assert_allclose(r, cv2.Rodrigues(rvecs[s])[0], atol=1e-9)
                np.testing.assert_allclose(t, tvecs[s].ravel(), atol=1e-9)


def test_depths_are_exact_on_exact_points():
    rng = np.random.default_rng(5)
    o2, _ = canonical_frame(PAPER_MARKER.feature_points)
    for r, t, xy in _views(PAPER_MARKER, rng, 100, 0.0):
        z = np.empty(4)
        assert point_depths(o2, np.ascontiguousarray(xy), z) == DEPTHS_OK
        np.testing.assert_allclose(z, (PAPER_MARKER.feature_points @ r.T + t)[:, 2], rtol=1e-11)


def test_non_planar_points_are_refused():
    import pytest

    with pytest.raises(ValueError, match="planar"):
        canonical_frame(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]))

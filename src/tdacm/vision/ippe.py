"""Planar pose from four points: Infinitesimal Plane-based Pose Estimation (IPPE) in numba.

Collins and Bartoli, "Infinitesimal Plane-Based Pose Estimation", IJCV 109 (2014). A planar
target seen by a calibrated camera has, up to noise, two poses that explain its image (the
classic two-fold ambiguity of a small planar target). IPPE computes both in closed form from
the homography ``H`` that maps the target plane to the normalized image:

1. ``H`` from the four correspondences (with ``H_22 = 1``: the exact 4-point homography, an
   8 x 8 linear system);
2. the image ``v`` of the plane's origin and the Jacobian ``J`` of the homography there,
   ``J = [[H00 - H20 H02, H01 - H21 H02], [H10 - H20 H12, H11 - H21 H12]]``;
3. ``R_v``, the rotation taking the optical axis ``e_z`` to the viewing ray ``[v; 1]``;
   ``B = [I_2 | -v] R_v[:, :2]``, ``A = B^-1 J``, ``gamma`` the largest singular value of
   ``A``, ``R_22 = A / gamma``; the first two columns of the rotation in the ray's frame are
   ``[R_22; +-b^T]`` with ``b = (sqrt(1 - |R_22[:, 0]|^2), s sqrt(1 - |R_22[:, 1]|^2))``
   (``s`` makes the columns orthogonal), the third their cross product; the two poses'
   rotations are ``R_v`` times those;
4. each rotation's translation by linear least squares on the reprojection equations
   ``t_x - x_k t_z = x_k (R X_k)_z - (R X_k)_x`` (and ``y``);
5. the poses are ordered by their reprojection error (the better one first).

The kernels take the target's points in a *canonical* frame (the plane ``z = 0``, two
coordinates per point) and return poses of that frame; :func:`canonical_frame` computes, once
per target, the canonical points and the transform back to the target's own frame. On exact
(noise-free) points both the pose and its depths are exact to rounding; this is the pose of
``cv2.solvePnPGeneric(..., SOLVEPNP_IPPE)`` (tested against it), without the call overhead and
callable from compiled code (the batched engine).
"""

from __future__ import annotations

import numpy as np
from numba import njit


def canonical_frame(object_points) -> tuple[np.ndarray, np.ndarray]:
    """``(points_2d (k, 2), g_canonical_to_target (4, 4))`` of a planar target's points
    ``(k, 3)`` (target frame): the points in a frame whose ``z = 0`` plane holds them (origin
    at their centroid), and that frame's pose in the target frame. ``ValueError`` if the
    points are not planar."""
    p = np.asarray(object_points, float)
    c = p.mean(axis=0)
    d = p - c
    _, s, vt = np.linalg.svd(d)
    if s[2] > 1e-9 * max(s[0], 1e-300):
        raise ValueError("the target's points are not planar")
    r = vt.copy()  # rows: in-plane axes, then the normal
    if np.linalg.det(r) < 0:
        r[2] = -r[2]
    if np.allclose(p[:, 2], 0.0):  # already in a z = 0 plane: keep its axes (readable poses)
        r = np.eye(3)
    g = np.eye(4)
    g[:3, :3] = r.T
    g[:3, 3] = c
    q2 = d @ r.T
    return np.ascontiguousarray(q2[:, :2]), g


@njit(cache=True)
def _homography4(obj, xy, h):
    """The homography ``H`` (3 x 3, ``H_22 = 1``) with ``H [X; Y; 1] ~ [x; y; 1]`` for four
    correspondences ``obj`` (4, 2) and ``xy`` (4, 2), into ``h``; False if singular."""
    a = np.zeros((8, 8))
    rhs = np.empty(8)
    for k in range(4):
        x0, y0 = obj[k, 0], obj[k, 1]
        u, v = xy[k, 0], xy[k, 1]
        r = 2 * k
        a[r, 0] = x0
        a[r, 1] = y0
        a[r, 2] = 1.0
        a[r, 6] = -u * x0
        a[r, 7] = -u * y0
        rhs[r] = u
        a[r + 1, 3] = x0
        a[r + 1, 4] = y0
        a[r + 1, 5] = 1.0
        a[r + 1, 6] = -v * x0
        a[r + 1, 7] = -v * y0
        rhs[r + 1] = v
    # Gaussian elimination with partial pivoting (8 x 8, once per frame)
    for c in range(8):
        piv = c
        big = abs(a[c, c])
        for r in range(c + 1, 8):
            if abs(a[r, c]) > big:
                big, piv = abs(a[r, c]), r
        if not big > 1e-300:
            return False
        if piv != c:
            for k in range(8):
                a[c, k], a[piv, k] = a[piv, k], a[c, k]
            rhs[c], rhs[piv] = rhs[piv], rhs[c]
        for r in range(c + 1, 8):
            f = a[r, c] / a[c, c]
            if f != 0.0:
                for k in range(c, 8):
                    a[r, k] -= f * a[c, k]
                rhs[r] -= f * rhs[c]
    sol = np.empty(8)
    for c in range(7, -1, -1):
        acc = rhs[c]
        for k in range(c + 1, 8):
            acc -= a[c, k] * sol[k]
        sol[c] = acc / a[c, c]
    for i in range(8):
        h[i // 3, i % 3] = sol[i]
    h[2, 2] = 1.0
    return True


@njit(cache=True)
def _ray_rotation(p, q, rv):
    """``R_v`` (into ``rv``): the rotation about ``e_z x t`` taking ``e_z`` to the unit ray
    ``t = [p, q, 1] / |[p, q, 1]|`` (Rodrigues' formula)."""
    nrm = np.sqrt(p * p + q * q + 1.0)
    t0, t1, t2 = p / nrm, q / nrm, 1.0 / nrm
    s = np.sqrt(t0 * t0 + t1 * t1)  # sin of the angle
    for i in range(3):
        for j in range(3):
            rv[i, j] = 1.0 if i == j else 0.0
    if s < 1e-15:
        return
    k0, k1 = -t1 / s, t0 / s  # unit axis (k2 = 0)
    c = t2
    one_c = 1.0 - c
    rv[0, 0] = c + k0 * k0 * one_c
    rv[0, 1] = k0 * k1 * one_c
    rv[0, 2] = k1 * s
    rv[1, 0] = k0 * k1 * one_c
    rv[1, 1] = c + k1 * k1 * one_c
    rv[1, 2] = -k0 * s
    rv[2, 0] = -k1 * s
    rv[2, 1] = k0 * s
    rv[2, 2] = c


@njit(cache=True)
def _translation(obj, xy, r, t):
    """Least-squares translation (into ``t``) of the pose with rotation ``r`` from the
    reprojection equations of the planar points ``obj`` (k, 2) seen at ``xy`` (k, 2)."""
    ata = np.zeros((3, 3))
    atb = np.zeros(3)
    for k in range(obj.shape[0]):
        x0, y0 = obj[k, 0], obj[k, 1]
        rx = r[0, 0] * x0 + r[0, 1] * y0
        ry = r[1, 0] * x0 + r[1, 1] * y0
        rz = r[2, 0] * x0 + r[2, 1] * y0
        u, v = xy[k, 0], xy[k, 1]
        # rows [1, 0, -u] and [0, 1, -v], right-hand sides u rz - rx and v rz - ry
        bu = u * rz - rx
        bv = v * rz - ry
        ata[0, 0] += 1.0
        ata[1, 1] += 1.0
        ata[0, 2] -= u
        ata[1, 2] -= v
        ata[2, 2] += u * u + v * v
        atb[0] += bu
        atb[1] += bv
        atb[2] -= u * bu + v * bv
    ata[2, 0] = ata[0, 2]
    ata[2, 1] = ata[1, 2]
    # the 3 x 3 symmetric solve by Cramer's rule (well conditioned: the rows [1, 0, -u])
    a, b, c = ata[0, 0], ata[0, 1], ata[0, 2]
    d, e, f = ata[1, 0], ata[1, 1], ata[1, 2]
    g, h, i = ata[2, 0], ata[2, 1], ata[2, 2]
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if not abs(det) > 1e-300:
        return False
    y0, y1, y2 = atb[0], atb[1], atb[2]
    t[0] = (y0 * (e * i - f * h) - b * (y1 * i - f * y2) + c * (y1 * h - e * y2)) / det
    t[1] = (a * (y1 * i - f * y2) - y0 * (d * i - f * g) + c * (d * y2 - y1 * g)) / det
    t[2] = (a * (e * y2 - y1 * h) - b * (d * y2 - y1 * g) + y0 * (d * h - e * g)) / det
    return True


@njit(cache=True)
def _reprojection(obj, xy, r, t):
    """Sum of squared reprojection errors (normalized coordinates) of the pose ``(r, t)``
    (whatever the points' depths: the pose's front is checked by its users)."""
    err = 0.0
    for k in range(obj.shape[0]):
        x0, y0 = obj[k, 0], obj[k, 1]
        px = r[0, 0] * x0 + r[0, 1] * y0 + t[0]
        py = r[1, 0] * x0 + r[1, 1] * y0 + t[1]
        pz = r[2, 0] * x0 + r[2, 1] * y0 + t[2]
        if pz == 0.0:
            return np.inf
        du = px / pz - xy[k, 0]
        dv = py / pz - xy[k, 1]
        err += du * du + dv * dv
    return err


@njit(cache=True)
def ippe_poses(obj, xy, rots, trans, errors):
    """Both IPPE poses (module docstring) of the canonical planar points ``obj`` (k, 2),
    ``k >= 4`` (the homography uses the first four), seen at normalized points ``xy`` (k, 2):
    rotations into ``rots`` (2, 3, 3), translations into ``trans`` (2, 3) and the squared
    reprojection errors into ``errors`` (2,), the better pose first (the order of
    ``cv2.solvePnPGeneric``; whether a pose puts the points in front is the caller's test). Returns False when the points admit no
    solution (a degenerate homography)."""
    h = np.empty((3, 3))
    if not _homography4(obj, xy, h):
        return False
    p, q = h[0, 2], h[1, 2]
    j00 = h[0, 0] - h[2, 0] * h[0, 2]
    j01 = h[0, 1] - h[2, 1] * h[0, 2]
    j10 = h[1, 0] - h[2, 0] * h[1, 2]
    j11 = h[1, 1] - h[2, 1] * h[1, 2]
    rv = np.empty((3, 3))
    _ray_rotation(p, q, rv)
    b00 = rv[0, 0] - p * rv[2, 0]
    b01 = rv[0, 1] - p * rv[2, 1]
    b10 = rv[1, 0] - q * rv[2, 0]
    b11 = rv[1, 1] - q * rv[2, 1]
    det = b00 * b11 - b01 * b10
    if not abs(det) > 1e-300:
        return False
    a00 = (b11 * j00 - b01 * j10) / det
    a01 = (b11 * j01 - b01 * j11) / det
    a10 = (-b10 * j00 + b00 * j10) / det
    a11 = (-b10 * j01 + b00 * j11) / det
    s00 = a00 * a00 + a01 * a01
    s01 = a00 * a10 + a01 * a11
    s11 = a10 * a10 + a11 * a11
    gamma2 = 0.5 * (s00 + s11 + np.sqrt((s00 - s11) * (s00 - s11) + 4.0 * s01 * s01))
    if not gamma2 > 1e-30:
        return False
    gamma = np.sqrt(gamma2)
    r00, r01, r10, r11 = a00 / gamma, a01 / gamma, a10 / gamma, a11 / gamma
    c0 = np.sqrt(max(1.0 - r00 * r00 - r10 * r10, 0.0))
    c1 = np.sqrt(max(1.0 - r01 * r01 - r11 * r11, 0.0))
    if -(r00 * r01 + r10 * r11) < 0.0:  # orthogonal columns: c0 c1 = -(r00 r01 + r10 r11)
        c1 = -c1
    rt = np.empty((3, 3))
    for sol in range(2):
        sg = 1.0 if sol == 0 else -1.0
        b0, b1 = sg * c0, sg * c1
        # [R_22; b^T] and the cross product of its two columns
        rt[0, 0], rt[0, 1], rt[0, 2] = r00, r01, r10 * b1 - b0 * r11
        rt[1, 0], rt[1, 1], rt[1, 2] = r10, r11, b0 * r01 - r00 * b1
        rt[2, 0], rt[2, 1], rt[2, 2] = b0, b1, r00 * r11 - r01 * r10
        for i in range(3):
            for j in range(3):
                rots[sol, i, j] = rv[i, 0] * rt[0, j] + rv[i, 1] * rt[1, j] + rv[i, 2] * rt[2, j]
        if not _translation(obj, xy, rots[sol], trans[sol]):
            return False
        errors[sol] = _reprojection(obj, xy, rots[sol], trans[sol])
    if errors[1] < errors[0]:
        for i in range(3):
            trans[0, i], trans[1, i] = trans[1, i], trans[0, i]
            for j in range(3):
                rots[0, i, j], rots[1, i, j] = rots[1, i, j], rots[0, i, j]
        errors[0], errors[1] = errors[1], errors[0]
    return True


@njit(cache=True)
def best_pose(obj, xy, r, t):
    """The better IPPE pose (:func:`ippe_poses`) into ``r`` (3, 3) and ``t`` (3,); False when
    the points admit none."""
    rots = np.empty((2, 3, 3))
    trans = np.empty((2, 3))
    errors = np.empty(2)
    if not ippe_poses(obj, xy, rots, trans, errors):
        return False
    r[:, :] = rots[0]
    t[:] = trans[0]
    return True


#: :func:`point_depths` results
DEPTHS_OK, NO_POSE, BEHIND = 0, 1, 2


@njit(cache=True)
def point_depths(obj, xy, depths):
    """Depths (into ``depths``, (k,)) of the canonical planar points ``obj`` (k, 2) seen at
    ``xy`` (k, 2) under the better IPPE pose: the paper's depth estimation from the known
    target geometry. Returns :data:`DEPTHS_OK`, :data:`NO_POSE` (a degenerate view) or
    :data:`BEHIND` (the better pose puts a point behind the camera)."""
    r = np.empty((3, 3))
    t = np.empty(3)
    if not best_pose(obj, xy, r, t):
        return NO_POSE
    for k in range(obj.shape[0]):
        z = r[2, 0] * obj[k, 0] + r[2, 1] * obj[k, 1] + t[2]
        if not z > 0.0:
            return BEHIND
        depths[k] = z
    return DEPTHS_OK

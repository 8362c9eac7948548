"""The paper's advanced image features and their analytic interaction matrix.

Paper, section "IBVS in Local Camera with Advanced Features": from four image points
``p_k = [u_k, v_k]`` (normalized coordinates in the virtual camera C_V, order 1 = top-left,
2 = bottom-left, 3 = bottom-right, 4 = top-right) the feature vector is

    p* = [p_phi, p_theta, p_psi, p_x, p_y, p_z]

* ``p_x, p_y``: centroid of the four points (paper's centroid equation);
* ``p_z``: perimeter ``|p2-p1| + |p3-p2| + |p4-p3| + |p4-p1|``;
* ``p_phi = 1/2 [atan((u2-u1)/(v1-v2)) - atan((u3-u4)/(v4-v3))]``   (eq. (33))
* ``p_theta = 1/2 [atan((v3-v2)/(u3-u2)) - atan((v4-v1)/(u4-u1))]`` (eq. (34))
* ``p_psi = 1/2 [atan((v1-v4)/(u4-u1)) + atan((v2-v3)/(u3-u2))]``   (eq. (35))

Robustification (the plain arctangent has period pi and divides by edge components that
vanish when an edge turns through 90 degrees):

1. Every ``atan(n/d)`` is evaluated as ``atan2(n', d')`` with the signs arranged so that
   ``d' > 0`` for an upright target, e.g. ``atan((u2-u1)/(v1-v2)) = atan2(u1-u2, v2-v1)``.
   For an upright target (each edge within 90 degrees of its nominal direction) this is
   *identical* to the paper's value; beyond, it continues smoothly instead of jumping by pi,
   and nothing is ever divided by a vanishing denominator. Because the detector labels the
   corners from the decoded marker (not from image position), the edge directions are
   defined over the full circle, so the yaw feature has period 2 pi.
2. Differences and means of two angles are taken on the circle:
   ``p_phi = 1/2 wrap(A1 - A2)``, ``p_theta = 1/2 wrap(B1 - B2)``,
   ``p_psi = wrap(C1 + 1/2 wrap(C2 - C1))`` with ``wrap`` onto ``(-pi, pi]``; these equal the
   paper's expressions whenever those are continuous.
3. The error (:func:`feature_error`) wraps the angular components onto ``(-pi, pi]``, i.e. the
   yaw error is measured relative to the desired value: a target yawed by 170 degrees gives
   an error of 170 degrees (not -10 degrees, the 180-degree-ambiguous answer of the plain
   ``atan``), so the servo turns the right way and converges to the right pose.

For a head-on view ``p_phi = p_theta = 0`` and ``p_psi`` is the camera's rotation about its
optical axis relative to the target (positive: camera turned clockwise as seen from behind,
the image turns the other way); ``p_phi`` reacts to rotations about the camera x axis and
``p_theta`` about its y axis with a gain of about the target's half-size over its depth.

The derivatives are unchanged by 1.-3. (``d atan2(n, d) = (d dn - n dd)/(n^2 + d^2)``, the
edge length squared in the denominator), so the interaction matrix is the chain rule

    J_img = (d p* / d points) @ [L_1; L_2; L_3; L_4]

with the point interaction matrices (ViSP and Corke, *linear-first* twist
``[v; w]``) ``Lx = [-1/Z, 0, x/Z, x y, -(1 + x^2), y]``,
``Ly = [0, -1/Z, y/Z, 1 + y^2, -x y, -x]``. This module returns interaction matrices whose
columns follow the model's **angular-first** twist ``[w; v]`` by default (the ViSP columns
permuted by :data:`LINEAR_TO_ANGULAR`); pass ``order="linear_first"`` for the ViSP layout.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import _checks as C
from .ippe import BEHIND, NO_POSE, canonical_frame, point_depths

#: Column permutation taking a linear-first ``[v; w]`` matrix to angular-first ``[w; v]``.
LINEAR_TO_ANGULAR = np.array([3, 4, 5, 0, 1, 2])

#: Indices of the angular features (wrapped in the error).
ANGULAR_FEATURES = (0, 1, 2)

FEATURE_NAMES = ("p_phi", "p_theta", "p_psi", "p_x", "p_y", "p_z")

_ORDERS = ("angular_first", "linear_first")


def wrap_angle(a):
    """Wrap angles onto ``(-pi, pi]``."""
    return np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2.0 * np.pi)


def angular_first(m: np.ndarray) -> np.ndarray:
    """Reorder the 6 columns of a linear-first ``[v; w]`` matrix to angular-first ``[w; v]``."""
    return np.asarray(m)[..., LINEAR_TO_ANGULAR]


def twist_linear_to_angular(v) -> np.ndarray:
    """``[v; w] -> [w; v]``."""
    v = C.array("twist", v, (6,))
    return np.concatenate((v[3:], v[:3]))


def twist_angular_to_linear(v) -> np.ndarray:
    """``[w; v] -> [v; w]``."""
    v = C.array("twist", v, (6,))
    return np.concatenate((v[3:], v[:3]))


def _check_points(points) -> np.ndarray:
    p = C.array("points", points, (4, 2))
    return p


def _check_depths(depths, n: int) -> np.ndarray:
    z = np.asarray(depths, dtype=float)
    if z.ndim == 0:
        z = np.full(n, float(z))
    z = C.array("depths", z, (n,))
    if np.any(z <= 0.0):
        raise ValueError(f"depths must be positive, got {z!r}")
    return z


def _check_order(order: str) -> None:
    if order not in _ORDERS:
        raise ValueError(f"order must be one of {_ORDERS}, got {order!r}")


# ---------------------------------------------------------------------- point features
def point_interaction_matrix(points, depths, order: str = "angular_first") -> np.ndarray:
    """Stacked interaction matrices ``(2N, 6)`` of normalized points ``(N, 2)``.

    Rows ``2k, 2k+1`` hold ``Lx, Ly`` of point ``k``; they map the camera twist (expressed in
    the camera frame) to ``[x_dot, y_dot]``. Columns: ``[w; v]`` (``order="angular_first"``,
    default) or ``[v; w]`` (``"linear_first"``, as in ViSP and Corke).
    """
    _check_order(order)
    p = C.points("points", points, 2)
    z = _check_depths(depths, p.shape[0])
    x, y = p[:, 0], p[:, 1]
    iz = 1.0 / z
    n = p.shape[0]
    m = np.zeros((2 * n, 6))
    m[0::2, 0] = -iz
    m[0::2, 2] = x * iz
    m[0::2, 3] = x * y
    m[0::2, 4] = -(1.0 + x * x)
    m[0::2, 5] = y
    m[1::2, 1] = -iz
    m[1::2, 2] = y * iz
    m[1::2, 3] = 1.0 + y * y
    m[1::2, 4] = -x * y
    m[1::2, 5] = -x
    return angular_first(m) if order == "angular_first" else m


# ---------------------------------------------------------------------- numba kernels
# The hot path (one call per control step): features, their Jacobian w.r.t. the points and
# the interaction matrix of four points, without Python overhead. The public functions
# below validate their inputs and call these.


@njit(cache=True)
def _wrap(a):
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


#: The six arctangent terms of the angular features, each a (numerator, denominator) pair of
#: differences ``p[i, a] - p[j, b]`` written ``(i, a, j, b)`` (points in the paper order TL, BL,
#: BR, TR; axis 0 = x, 1 = y). The features and their Jacobian both read this table.
_TERMS = np.array(
    [
        [[0, 0, 1, 0], [1, 1, 0, 1]],
        [[3, 0, 2, 0], [2, 1, 3, 1]],
        [[2, 1, 1, 1], [2, 0, 1, 0]],
        [[3, 1, 0, 1], [3, 0, 0, 0]],
        [[0, 1, 3, 1], [3, 0, 0, 0]],
        [[1, 1, 2, 1], [2, 0, 1, 0]],
    ]
)


@njit(cache=True)
def _terms(p):
    """(numerator, denominator) of the six arctangents (:data:`_TERMS`)."""
    t = np.empty((6, 2))
    for k in range(6):
        for m in range(2):
            d = _TERMS[k, m]
            t[k, m] = p[d[0], d[1]] - p[d[2], d[3]]
    return t


_EDGES = np.array([[0, 1], [1, 2], [2, 3], [0, 3]])


@njit(cache=True)
def _features_kernel(p):
    t = _terms(p)
    a = np.empty(6)
    for i in range(6):
        a[i] = np.arctan2(t[i, 0], t[i, 1])
    f = np.empty(6)
    f[0] = 0.5 * _wrap(a[0] - a[1])
    f[1] = 0.5 * _wrap(a[2] - a[3])
    f[2] = _wrap(a[4] + 0.5 * _wrap(a[5] - a[4]))
    f[3] = 0.25 * (p[0, 0] + p[1, 0] + p[2, 0] + p[3, 0])
    f[4] = 0.25 * (p[0, 1] + p[1, 1] + p[2, 1] + p[3, 1])
    per = 0.0
    for e in range(4):
        i, j = _EDGES[e, 0], _EDGES[e, 1]
        per += np.hypot(p[j, 0] - p[i, 0], p[j, 1] - p[i, 1])
    f[5] = per
    return f


@njit(cache=True)
def _jacobian_kernel(p):
    t = _terms(p)
    g = np.zeros((6, 8))
    for k in range(6):
        n, d = t[k, 0], t[k, 1]
        r2 = n * n + d * d
        num, den = _TERMS[k, 0], _TERMS[k, 1]
        for m in range(2):  # the first point of each difference (sign +1), then the second
            sign = 1.0 - 2.0 * m
            g[k, 2 * num[2 * m] + num[2 * m + 1]] += sign * d / r2
            g[k, 2 * den[2 * m] + den[2 * m + 1]] -= sign * n / r2
    jac = np.zeros((6, 8))
    for c in range(8):
        jac[0, c] = 0.5 * (g[0, c] - g[1, c])
        jac[1, c] = 0.5 * (g[2, c] - g[3, c])
        jac[2, c] = 0.5 * (g[4, c] + g[5, c])
    for k in range(4):
        jac[3, 2 * k] = 0.25
        jac[4, 2 * k + 1] = 0.25
    for e in range(4):
        i, j = _EDGES[e, 0], _EDGES[e, 1]
        dx = p[j, 0] - p[i, 0]
        dy = p[j, 1] - p[i, 1]
        ln = np.hypot(dx, dy)
        jac[5, 2 * j] += dx / ln
        jac[5, 2 * j + 1] += dy / ln
        jac[5, 2 * i] -= dx / ln
        jac[5, 2 * i + 1] -= dy / ln
    return jac


@njit(cache=True)
def _points_kernel(p, z):
    """Stacked point interaction matrices, angular-first ``[w; v]`` columns."""
    n = p.shape[0]
    m = np.zeros((2 * n, 6))
    for k in range(n):
        x, y, iz = p[k, 0], p[k, 1], 1.0 / z[k]
        m[2 * k, 0] = x * y
        m[2 * k, 1] = -(1.0 + x * x)
        m[2 * k, 2] = y
        m[2 * k, 3] = -iz
        m[2 * k, 5] = x * iz
        m[2 * k + 1, 0] = 1.0 + y * y
        m[2 * k + 1, 1] = -x * y
        m[2 * k + 1, 2] = -x
        m[2 * k + 1, 4] = -iz
        m[2 * k + 1, 5] = y * iz
    return m


@njit(cache=True)
def _interaction_kernel(p, z):
    return _jacobian_kernel(p) @ _points_kernel(p, z)


@njit(cache=True)
def min_edge2(p):
    """The smallest ``num^2 + den^2`` of the six arctangent terms of the points ``p`` (4, 2):
    below ``1e-24`` the features are undefined (coincident corners)."""
    t = _terms(p)
    best = np.inf
    for k in range(t.shape[0]):
        best = min(best, t[k, 0] ** 2 + t[k, 1] ** 2)
    return best


def min_edge2_of(p) -> float:
    """:func:`min_edge2` of any ``(4, 2)`` points."""
    return float(min_edge2(np.ascontiguousarray(p, dtype=float)))


# ---------------------------------------------------------------------- advanced features
def advanced_features(points) -> np.ndarray:
    """Feature vector ``p* = [p_phi, p_theta, p_psi, p_x, p_y, p_z]`` (paper, eqs. (33)-(35)
    and the centroid and perimeter equations) of four normalized points ``(4, 2)`` in the
    paper's order (TL, BL, BR, TR), robustified as described in the module docstring.

    The angles are in radians, ``p_psi`` in ``(-pi, pi]``."""
    p = _check_points(points)
    if min_edge2_of(p) < 1e-24:
        raise ValueError("points must be four distinct corners (an edge has zero length)")
    return _features_kernel(p)


def paper_features(points) -> np.ndarray:
    """The paper's features with the plain ``atan`` (eqs. (33)-(35) verbatim), for reference
    and tests; undefined (division by zero) or off by pi/2 once an edge turns past 90 degrees.
    """
    p = _check_points(points)
    (u1, v1), (u2, v2), (u3, v3), (u4, v4) = p
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.array(
            [
                0.5 * (np.arctan((u2 - u1) / (v1 - v2)) - np.arctan((u3 - u4) / (v4 - v3))),
                0.5 * (np.arctan((v3 - v2) / (u3 - u2)) - np.arctan((v4 - v1) / (u4 - u1))),
                0.5 * (np.arctan((v1 - v4) / (u4 - u1)) + np.arctan((v2 - v3) / (u3 - u2))),
                p[:, 0].mean(),
                p[:, 1].mean(),
                _perimeter(p),
            ]
        )
    return f


def _perimeter(p) -> float:
    e = (p[1] - p[0], p[2] - p[1], p[3] - p[2], p[3] - p[0])
    return float(sum(np.hypot(d[0], d[1]) for d in e))


def features_jacobian(points) -> np.ndarray:
    """``d p* / d [x1, y1, x2, y2, x3, y3, x4, y4]`` (6 x 8), analytic:
    ``d atan2(n, d) = (d dn - n dd) / (n^2 + d^2)`` for the angle terms, ``1/4`` for the
    centroid, unit edge directions for the perimeter."""
    p = _check_points(points)
    if min_edge2_of(p) < 1e-24:
        raise ValueError("points must be four distinct corners (an edge has zero length)")
    return _jacobian_kernel(p)


def checked_view(points, depths) -> tuple[np.ndarray, np.ndarray]:
    """``(points (4, 2), depths (4,))`` as float arrays, or ``ValueError``: the corners must be
    distinct and the depths (one value or four) positive (what :func:`_interaction_kernel`
    needs)."""
    p = _check_points(points)
    z = _check_depths(depths, 4)
    if min_edge2_of(p) < 1e-24:
        raise ValueError("points must be four distinct corners (an edge has zero length)")
    return p, z


def feature_interaction_matrix(points, depths, order: str = "angular_first") -> np.ndarray:
    """Analytic 6 x 6 interaction matrix ``J_img`` of :func:`advanced_features`:
    ``d p*/dt = J_img v`` for the camera twist ``v`` in the camera frame, ``[w; v]`` by
    default (``order="linear_first"`` for ``[v; w]``).

    ``depths``: depth ``Z`` of each of the four points (``(4,)``) or one common value, e.g.
    from :func:`estimate_depths` or the known target size (:func:`depth_from_size`).
    """
    _check_order(order)
    p, z = checked_view(points, depths)
    m = _interaction_kernel(p, z)
    return m if order == "angular_first" else m[:, [3, 4, 5, 0, 1, 2]]


def feature_error(features, desired) -> np.ndarray:
    """``e = p* - p*_d`` with the angular components wrapped onto ``(-pi, pi]``."""
    f = C.array("features", features, (6,))
    fd = C.array("desired", desired, (6,))
    e = f - fd
    e[:3] = wrap_angle(e[:3])
    return e


# ---------------------------------------------------------------------- depth
def estimate_depths(points, object_points) -> np.ndarray:
    """Depths ``(4,)`` of the four feature points from their normalized image coordinates
    and the known target geometry (``object_points`` ``(4, 3)``, same order, planar), by
    planar PnP (the better IPPE pose, :mod:`tdacm.vision.ippe`: the pose of
    ``cv2.solvePnP`` with ``SOLVEPNP_IPPE`` and unit intrinsics)."""
    z, why = _estimate_depths(
        _check_points(points), C.array("object_points", object_points, (4, 3))
    )
    if z is None:
        raise ValueError(why)
    return z


def _estimate_depths(p: np.ndarray, obj: np.ndarray, obj_2d=None):
    """:func:`estimate_depths` on checked points ``(4, 2)`` and object points ``(4, 3)`` (or
    their canonical plane coordinates ``obj_2d``, :func:`~tdacm.vision.ippe.canonical_frame`,
    computed once by the perception block): ``(depths, None)``, or ``(None, why)`` when the
    points admit no pose with the target in front of the camera (noisy corners do: the
    perception block then rejects the frame)."""
    if obj_2d is None:
        obj_2d = canonical_frame(obj)[0]
    z = np.empty(4)
    status = point_depths(obj_2d, np.ascontiguousarray(p, dtype=float), z)
    if status == NO_POSE:
        return None, "pose estimation failed for these points"
    if status == BEHIND:
        return None, "pose estimation put the target behind the camera"
    return z, None


def depth_from_size(points, perimeter: float) -> float:
    """One depth for all points from the known metric perimeter of the feature polygon:
    ``Z = perimeter / p_z`` (exact for a fronto-parallel target)."""
    per = C.positive("perimeter", perimeter)
    return per / _perimeter(_check_points(points))

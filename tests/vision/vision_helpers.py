"""Helpers shared by the vision tests (a kinematic stand-in for the coupled model and a
camera-pose helper). Kept out of conftest.py so that tests import them by a unique name."""

from __future__ import annotations

import numpy as np

from tdacm.lie.euler import rot_zyx
from tdacm.lie.se3 import expmap, inv_se3, vee

#: Lines appended by the closed-loop tests, printed in pytest's terminal summary.
LOOP_REPORT: list[str] = []


class FakeRod:
    length = 1.0
    diameter = 0.002


class FakeSystem:
    """Kinematic TD-ACM: drone ``q[:6]`` (ZYX Euler, inertial position), attachment
    ``Ry(90 deg)`` 0.1 m below the CoM, rod of constant curvature ``(k_y, k_z) = q[6:8]``
    (x along the backbone). ``tip_jacobian`` by central differences of the body twist."""

    n = 8
    floating = True
    rod = FakeRod()

    def __init__(self):
        a = np.eye(4)
        a[:3, :3] = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
        a[2, 3] = -0.1
        self.attachment = a

    def base_pose(self, q):
        g = np.eye(4)
        g[:3, :3] = rot_zyx(q[0], q[1], q[2])
        g[:3, 3] = q[3:6]
        return g

    def pose(self, q, s):
        xi = np.array([0.0, q[6], q[7], 1.0, 0.0, 0.0]) * s
        return self.base_pose(q) @ self.attachment @ expmap(xi)

    def tip_pose(self, q):
        return self.pose(q, self.rod.length)

    def backbone(self, q, n_points):
        return np.array([self.pose(q, s) for s in np.linspace(0, self.rod.length, n_points)])

    def tip_jacobian(self, q, h=1e-6):
        q = np.asarray(q, float)
        g_inv = inv_se3(self.tip_pose(q))
        jac = np.zeros((6, self.n))
        for i in range(self.n):
            dq = np.zeros(self.n)
            dq[i] = h
            dg = (self.tip_pose(q + dq) - self.tip_pose(q - dq)) / (2 * h)
            jac[:, i] = vee(g_inv @ dg)
        return jac


def tilted_view(scene, distance, yaw_deg, tilt_x_deg=0.0, tilt_y_deg=0.0):
    """Camera pose looking at the target from ``distance``, rotated by ``yaw_deg`` about the
    optical axis and tilted about the target centre (the target stays near the centre)."""
    from scipy.spatial.transform import Rotation

    g = scene.viewing_pose(distance, yaw_deg)
    rt = Rotation.from_euler("xy", np.radians([tilt_x_deg, tilt_y_deg])).as_matrix()
    c = scene.target_pose[:3, 3]
    out = g.copy()
    out[:3, :3] = rt @ g[:3, :3]
    out[:3, 3] = c + rt @ (g[:3, 3] - c)
    return out

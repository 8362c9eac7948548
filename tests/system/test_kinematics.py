"""Poses and Jacobians against finite differences (paper eqs. (5)-(10))."""

import numpy as np
import pytest

import tdacm
from tdacm.lie.se3 import inv_se3, vee

from .conftest import random_state


def fd_jacobian(system, q, s, eps=1e-6):
    g0 = system.pose(q, s)
    j = np.zeros((6, system.n))
    for i in range(system.n):
        dq = np.zeros(system.n)
        dq[i] = eps
        j[:, i] = vee(inv_se3(g0) @ (system.pose(q + dq, s) - system.pose(q - dq, s)) / (2 * eps))
    return j


@pytest.mark.parametrize("which", ["paper", "rich"])
@pytest.mark.parametrize("s", [0.0, 0.13, 0.5, 0.871, 1.0])
def test_jacobian_matches_finite_differences(which, s, request):
    system = request.getfixturevalue(which)
    q, _ = random_state(system, seed=3)
    j = system.jacobian(q, s)
    jfd = fd_jacobian(system, q, s)
    # drone columns and rod columns separately, so a failure says which part is wrong
    assert np.allclose(j[:, :6], jfd[:, :6], atol=1e-8)
    assert np.allclose(j[:, 6:], jfd[:, 6:], atol=1e-8)


@pytest.mark.parametrize("which", ["paper", "rich"])
def test_tip_jacobian_rate_matches_finite_differences(which, request):
    system = request.getfixturevalue(which)
    q, qd = random_state(system, seed=5)
    h = 1e-6
    fd = (system.tip_jacobian(q + h * qd) - system.tip_jacobian(q - h * qd)) / (2 * h)
    assert np.allclose(system.tip_jacobian_dot(q, qd), fd, atol=1e-8)
    fd_mid = (system.jacobian(q + h * qd, 0.4) - system.jacobian(q - h * qd, 0.4)) / (2 * h)
    assert np.allclose(system.jacobian_dot(q, qd, 0.4), fd_mid, atol=1e-8)


def test_tip_pose_is_pose_at_length_and_backbone_ends_there(paper):
    q, _ = random_state(paper, seed=2)
    assert np.allclose(paper.tip_pose(q), paper.pose(q, paper.rod.length), atol=1e-14)
    bb = paper.backbone(q, 11)
    assert bb.shape == (11, 4, 4)
    assert np.allclose(bb[0], paper.base_pose(q) @ paper.attachment)
    # order-0 basis: constant strain, so every Magnus discretization is exact
    assert np.allclose(bb[-1], paper.tip_pose(q), atol=1e-12)


def test_constant_curvature_tip_is_a_circular_arc():
    system = tdacm.paper_system(fixed_base_pose=np.eye(4))
    kz = 0.7
    g = system.tip_pose([0.0, kz])
    # in the attachment frame the tip is at (sin(kL)/k, (1-cos kL)/k, 0)
    local = inv_se3(system.attachment) @ g
    assert np.allclose(local[:3, 3], [np.sin(kz) / kz, (1 - np.cos(kz)) / kz, 0.0], atol=1e-14)


def test_rod_hangs_below_the_drone(paper):
    q = np.zeros(8)
    q[5] = 3.0
    tip = paper.tip_pose(q)
    assert np.allclose(tip[:3, 3], [0, 0, 3.0 - 0.1 - 1.0])
    assert np.allclose(tip[:3, 0], [0, 0, -1])  # backbone (local x) points down

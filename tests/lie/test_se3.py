"""SE(3) kernels: identities, exponential, tangent operator, structured block products."""

import numpy as np
import pytest
from scipy.linalg import expm

from tdacm.lie import blocks, se3
from tdacm.lie.euler import euler_rate_matrix, euler_rate_matrix_dot, rot_zyx

rng = np.random.default_rng(1)


def random_twist(scale=1.0):
    return rng.normal(size=6) * scale


def random_pose():
    return se3.expmap(random_twist())


def test_hat_vee_roundtrip():
    x = random_twist()
    assert np.allclose(se3.vee(se3.hat(x)), x)
    assert np.allclose(se3.skew(x[:3]) @ x[3:], np.cross(x[:3], x[3:]))


def test_adjoint_identities():
    g1, g2 = random_pose(), random_pose()
    x, y = random_twist(), random_twist()
    assert np.allclose(se3.Ad(g1) @ se3.Ad_inv(g1), np.eye(6), atol=1e-12)
    assert np.allclose(se3.Ad(g1 @ g2), se3.Ad(g1) @ se3.Ad(g2), atol=1e-12)
    # Ad(g) x^ = g x^ g^-1
    assert np.allclose(se3.hat(se3.Ad(g1) @ x), g1 @ se3.hat(x) @ se3.inv_se3(g1), atol=1e-12)
    # ad is the Lie bracket
    assert np.allclose(se3.hat(se3.ad(x) @ y), se3.hat(x) @ se3.hat(y) - se3.hat(y) @ se3.hat(x))
    assert np.allclose(se3.ad(x) @ y, -se3.ad(y) @ x)
    assert np.allclose(se3.coad(x), -se3.ad(x).T)
    # coad(eta) mu = -S(mu) eta and S is skew
    mu = random_twist()
    s = se3.wrench_skew(mu)
    assert np.allclose(s, -s.T)
    assert np.allclose(se3.coad(x) @ mu, -s @ x)


@pytest.mark.parametrize("scale", [1e-9, 1e-3, 0.2, 0.99, 1.01, 3.0])
def test_exp_matches_matrix_exponential(scale):
    x = random_twist(scale)
    assert np.allclose(se3.expmap(x), expm(se3.hat(x)), atol=1e-13, rtol=1e-12)
    r, p = blocks.expmap_rp(x)
    assert np.allclose(r, expm(se3.hat(x))[:3, :3], atol=1e-13)
    assert np.allclose(p, expm(se3.hat(x))[:3, 3], atol=1e-13)


@pytest.mark.parametrize("scale", [1e-6, 0.1, 0.5, 0.99, 1.01, 2.5])
def test_tangent_operator_against_finite_differences(scale):
    """exp(O)^-1 d/de exp(O + e d) = (Ad(exp O)^-1 T(O) d)^."""
    om, d = random_twist(scale), random_twist()
    eps = 1e-6
    fd = (expm(se3.hat(om + eps * d)) - expm(se3.hat(om - eps * d))) / (2 * eps)
    lhs = se3.vee(se3.inv_se3(se3.expmap(om)) @ fd)
    rhs = se3.Ad_inv(se3.expmap(om)) @ se3.tangent(om) @ d
    assert np.allclose(lhs, rhs, atol=1e-8)


def test_tangent_matches_series_and_rate_matches_fd():
    om, od = random_twist(0.8), random_twist()
    series = np.eye(6)
    term = np.eye(6)
    for k in range(1, 30):
        term = term @ se3.ad(om) / (k + 1)
        series = series + term
    assert np.allclose(se3.tangent(om), series, atol=1e-13)
    for scale in (1e-4, 0.2, 0.3, 2.0):
        om = random_twist(scale)
        t, dt = se3.tangent_and_rate(om, od)
        eps = 1e-6
        fd = (se3.tangent(om + eps * od) - se3.tangent(om - eps * od)) / (2 * eps)
        assert np.allclose(dt, fd, atol=1e-8)
        assert np.allclose(t, se3.tangent(om))


def test_small_angle_branch_is_continuous():
    """The Taylor branch and the closed form agree at the switch angle (to the closed form's
    own cancellation error, about eps / th^8)."""
    below = se3.tangent_coefficients(se3.SMALL_ANGLE * (1 - 1e-12))
    above = se3.tangent_coefficients(se3.SMALL_ANGLE * (1 + 1e-12))
    for a, b in zip(below, above, strict=True):
        assert np.allclose(a, b, rtol=1e-11, atol=0), (a, b)


def test_block_products_match_dense():
    xi, x = random_twist(), rng.normal(size=(6, 5))
    out = np.empty_like(x)
    blocks.ad_apply(xi, x, out)
    assert np.allclose(out, se3.ad(xi) @ x)
    g = random_pose()
    y = x.copy()
    blocks.adinv_apply(g[:3, :3].copy(), g[:3, 3].copy(), y)
    assert np.allclose(y, se3.Ad_inv(g) @ x)
    mu = random_twist()
    z = np.zeros_like(x)
    blocks.skew_apply_sub(mu, x, z)
    assert np.allclose(z, -se3.wrench_skew(mu) @ x)
    om, od = random_twist(0.5), random_twist()
    tz, tdz = blocks.tangent_apply(om, od, x, True)
    t, dt = se3.tangent_and_rate(om, od)
    assert np.allclose(tz, t @ x) and np.allclose(tdz, dt @ x)


def test_euler_rate_matrix():
    """w_b^ = R^T R_dot for R = Rz Ry Rx, and T_dot against finite differences."""
    phi, theta, psi = 0.3, -0.4, 1.1
    rates = np.array([0.7, -0.2, 0.5])
    eps = 1e-6
    a = np.array([phi, theta, psi])
    rdot = (rot_zyx(*(a + eps * rates)) - rot_zyx(*(a - eps * rates))) / (2 * eps)
    w = se3.unskew(rot_zyx(*a).T @ rdot)
    assert np.allclose(w, euler_rate_matrix(phi, theta) @ rates, atol=1e-9)
    tdot_fd = (
        euler_rate_matrix(*(a + eps * rates)[:2]) - euler_rate_matrix(*(a - eps * rates)[:2])
    ) / (2 * eps)
    assert np.allclose(euler_rate_matrix_dot(phi, theta, *rates[:2]), tdot_fd, atol=1e-9)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.3, 2.0, np.pi - 1e-3, np.pi - 1e-8])
def test_so3_log_inverts_the_exponential(angle):
    """``log(exp(w~)) = w`` from 0 to pi (at pi up to the sign of the axis)."""
    rng = np.random.default_rng(int(1e6 * angle) % 2**31)
    for _ in range(20):
        axis = rng.normal(size=3)
        w = angle * axis / np.linalg.norm(axis)
        r = expm(se3.skew(w))
        got = se3.so3_log(r)
        if np.pi - angle < 1e-6:
            got = got if got @ w > 0 else -got
        np.testing.assert_allclose(got, w, atol=1e-7 if np.pi - angle < 1e-6 else 1e-12)
        np.testing.assert_allclose(expm(se3.skew(got)), r, atol=1e-12)


def test_adjoint_pair_matches_the_kernels():
    rng = np.random.default_rng(7)
    for _ in range(50):
        g = se3.expmap(rng.standard_normal(6))
        ad, ad_inv = se3.adjoint_pair(g)
        np.testing.assert_allclose(ad, se3.Ad(g), rtol=0, atol=1e-15)
        np.testing.assert_allclose(ad_inv, se3.Ad_inv(g), rtol=0, atol=1e-15)


def test_so3_exp_and_left_jacobian_against_finite_differences():
    rng = np.random.default_rng(0)
    for theta in (np.zeros(3), 1e-5 * rng.normal(size=3), 0.3 * rng.normal(size=3)):
        rot, jl = se3.so3_exp_and_left_jacobian(theta)
        np.testing.assert_allclose(rot, se3.expmap(np.r_[theta, 0.0, 0.0, 0.0])[:3, :3], atol=1e-13)
        eps = 1e-6
        for j in range(3):
            d = np.zeros(3)
            d[j] = eps
            # exp(theta + d) = exp(J_l d) exp(theta): the rotation vector of the left increment
            inc = se3.so3_exp_and_left_jacobian(theta + d)[0] @ rot.T
            w = np.array([inc[2, 1] - inc[1, 2], inc[0, 2] - inc[2, 0], inc[1, 0] - inc[0, 1]])
            np.testing.assert_allclose(w / (2 * eps), jl[:, j], atol=1e-6)

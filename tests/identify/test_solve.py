"""The structured least-squares solve of a multiple-shooting fit (window states eliminated
block by block) against the dense one: same estimates, same covariances."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

from tdacm.identify import DEFAULT_TRUTH, synthesize
from tdacm.identify.fit import Problem, input_noise_covariance, sandwich_covariance
from tdacm.identify.solve import Blocks, levenberg_marquardt, parameter_rows


@pytest.fixture(scope="module")
def small():
    # 4 s of the loaded steps, 1 s windows: E and the tip mass well conditioned (1 %)
    rec = synthesize("tendon-steps-loaded", seed=3, duration=4.0).decimated(2)
    prob = Problem([rec], ["E", "tip_mass"], segment=1.0)
    return prob, prob.initial({k: 1.03 * DEFAULT_TRUTH[k] for k in ("E", "tip_mass")})


def test_structured_solve_equals_the_dense_least_squares(small):
    prob, z0 = small
    dense = least_squares(prob.residual, z0, jac=prob.jacobian, method="trf", x_scale="jac",
                          ftol=1e-13, xtol=1e-13, gtol=1e-13, max_nfev=60)  # fmt: skip
    ours = levenberg_marquardt(prob.residual, prob.jacobian, z0, prob.blocks, ftol=1e-13,
                               xtol=1e-13, max_nfev=60)  # fmt: skip
    assert ours.success
    # log-parameters: the difference is relative
    np.testing.assert_allclose(ours.x[:2], dense.x[:2], rtol=0, atol=1e-8)
    assert 2 * ours.cost == pytest.approx(2 * dense.cost, rel=1e-10)


def test_parameter_rows_equal_the_dense_pseudo_inverse(small):
    prob, z0 = small
    jac = prob.jacobian(z0)
    r = prob.residual(z0)
    a = np.linalg.pinv(jac.T @ jac)
    h, f_inv = parameter_rows(jac, prob.blocks)
    np.testing.assert_allclose(f_inv, a[:2, :2], rtol=1e-8)
    np.testing.assert_allclose(h, a[:2] @ jac.T, rtol=0, atol=1e-8 * np.abs(h).max())
    cov, _ = sandwich_covariance(prob, jac, r, 2)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_damped_step_equals_the_dense_solve():
    # a random block-structured Jacobian: (J^T J + lam D) delta = -J^T r, eliminated by blocks
    rng = np.random.default_rng(5)
    p, k, nw, rows = 3, 4, 5, 30
    jac = np.zeros((nw * rows, p + nw * k))
    jac[:, :p] = rng.standard_normal((nw * rows, p))
    blocks = Blocks(p, [], [])
    for w in range(nw):
        jac[w * rows : (w + 1) * rows, p + w * k : p + (w + 1) * k] = rng.standard_normal((rows, k))
        blocks.rows.append((w * rows, (w + 1) * rows))
        blocks.cols.append((p + w * k, p + (w + 1) * k))
    r = rng.standard_normal(nw * rows)
    from tdacm.identify.solve import _scaling, normal, solve_damped

    ne = normal(jac, r, blocks)
    dp, ds = _scaling(ne)
    lam = 0.3
    got_p, got_s = solve_damped(ne, lam, dp, ds)
    jtj = jac.T @ jac
    want = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj)), -jac.T @ r)
    np.testing.assert_allclose(np.r_[got_p, np.concatenate(got_s)], want, rtol=1e-10)


def test_input_noise_moves_the_estimate_as_its_first_order_map(small):
    # the covariance of tension noise (input_noise_covariance) rests on d(theta) = -h dr:
    # refit with one draw of 2 % tension noise and compare with the first-order prediction
    prob, z0 = small
    sol = levenberg_marquardt(prob.residual, prob.jacobian, z0, prob.blocks, ftol=1e-12,
                              xtol=1e-12, max_nfev=40)  # fmt: skip
    h, _ = parameter_rows(sol.jac, prob.blocks)
    rec = prob.setups[0].rec
    u = rec.u.copy()
    u[:, -4:] *= 1.0 + 0.02 * np.random.default_rng(9).standard_normal((len(u), 4))
    prob2 = Problem([replace(rec, u=u)], prob.names, segment=1.0)
    sol2 = levenberg_marquardt(prob2.residual, prob2.jacobian, sol.x, prob2.blocks,
                               ftol=1e-12, xtol=1e-12, max_nfev=40)  # fmt: skip
    moved = sol2.x[:2] - sol.x[:2]
    predicted = -h @ (prob2.residual(sol.x) - sol.fun)
    assert np.all(np.abs(moved) > 1e-5)  # the noise moves the estimates measurably
    np.testing.assert_allclose(moved, predicted, rtol=0.05)  # second-order terms: a few %
    # the windows' shares are independent: their per-window estimate equals the spread of
    # the total first-order move over independent draws (48 draws: ~10 % sampling error each)
    cov = input_noise_covariance(prob, sol.x, h, draws=8)
    rng = np.random.default_rng(1)
    moves = []
    for _ in range(48):
        ud = rec.u.copy()
        ud[:, -4:] *= 1.0 + 0.02 * rng.standard_normal((len(ud), 4))
        p2 = Problem([replace(rec, u=ud)], prob.names, segment=1.0)
        moves.append(-h @ (p2.residual(sol.x) - sol.fun))
    spread = np.sqrt(np.mean(np.square(moves), axis=0))
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), spread, rtol=0.3)

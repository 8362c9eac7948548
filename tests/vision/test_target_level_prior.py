"""The target filter's level prior (docs/control.md, "Target filter"): a target on a level
surface has its normal along gravity, which informs exactly the two weakly observed tilt
directions. In this file's geometry (``test_robust_servo``) the target sits at the origin
with its z axis along world +z, away from the camera."""

from __future__ import annotations

import numpy as np
import pytest

from tdacm.lie.se3 import expmap, so3_log
from tdacm.sim.scenario import ScenarioError, load_scenario
from tdacm.vision import LOCAL_CAMERA, PAPER_MARKER, SceneConfig, TargetFilter
from tdacm.vision.kinematic import project_points

SIGMA_PX = 1.0
UP = (0.0, 0.0, 1.0)  # the target's z axis in this geometry


def _camera(distance, lateral=(0.0, 0.0)):
    g = np.eye(4)
    g[:3, 3] = [lateral[0], lateral[1], -distance]
    return g


def _pixels(g_cam, g_target=None):
    g_target = np.eye(4) if g_target is None else g_target
    xy, _ = project_points(PAPER_MARKER.feature_points, np.linalg.solve(g_target, g_cam))
    return LOCAL_CAMERA.denormalize(xy)


def _tilt(rx, ry):
    return expmap(np.array([rx, ry, 0.0, 0.0, 0.0, 0.0]))


def _filter(prior_deg, **kw):
    return TargetFilter(
        LOCAL_CAMERA, PAPER_MARKER.feature_points, pixel_sigma=SIGMA_PX,
        level_prior=np.radians(prior_deg), level_normal=UP, **kw,
    )  # fmt: skip


def test_prior_information_is_on_the_tilt_only():
    """At a level target the prior adds ``diag(1, 1, 0, 0, 0, 0) / sigma_p^2``."""
    f = _filter(0.5)
    poses = [_camera(1.5, (0.002 * k, 0.0)) for k in range(20)]
    extra = f.information(np.eye(4), poses, with_prior=True) - f.information(np.eye(4), poses)
    expected = np.zeros((6, 6))
    expected[0, 0] = expected[1, 1] = 1.0 / np.radians(0.5) ** 2
    np.testing.assert_allclose(extra, expected, atol=1e-6 * expected.max())


def test_prior_jacobian_matches_finite_differences():
    f = _filter(1.0)
    pose = _tilt(0.03, -0.02) @ expmap(np.array([0.0, 0.0, 0.4, 0.1, 0.2, 0.0]))
    info, grad, cost = f._prior_terms(pose)
    w = 1.0 / np.radians(1.0) ** 2
    assert np.linalg.eigvalsh(info).min() > -1e-9 * w  # positive semi-definite, rank 2
    assert np.linalg.matrix_rank(info, tol=1e-6 * w) == 2

    def m_xy(g):
        return (g[:3, :3].T @ np.array(UP))[:2]

    eps = 1e-7
    jac = np.empty((2, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        jac[:, k] = (m_xy(pose @ expmap(d)) - m_xy(pose)) / eps
    np.testing.assert_allclose(w * jac.T @ jac, info, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(w * jac.T @ (-m_xy(pose)), grad, rtol=1e-5, atol=1e-6)
    assert cost == pytest.approx(w * float(m_xy(pose) @ m_xy(pose)))


def _static_run(prior_deg, true_tilt, seed, frames=150):
    g_t = _tilt(*true_tilt)
    g_cam = _camera(1.5)
    pix = _pixels(g_cam, g_t)
    rng = np.random.default_rng(seed)
    f = _filter(prior_deg)
    for _ in range(frames):
        f.update(pix + rng.normal(0, SIGMA_PX, pix.shape), g_cam)
    err = np.linalg.solve(g_t, f.pose)
    return so3_log(np.ascontiguousarray(err[:3, :3]))[:2], f.P[:2, :2]


def test_prior_shrinks_the_tilt_error_and_stays_consistent():
    """True tilts drawn from the prior itself (a board level to 0.5 deg): the posterior tilt
    error is smaller than without the prior and its NEES is chi-square with 2 dof (12
    seeds: mean within [0.9, 3.5], the 99 % band of the mean of 12 chi2(2) draws)."""
    rng = np.random.default_rng(7)
    sp = np.radians(0.5)
    nees, with_p, without = [], [], []
    for seed in range(12):
        tilt = rng.normal(0.0, sp, 2)
        e, p = _static_run(0.5, tilt, seed)
        nees.append(float(e @ np.linalg.solve(p, e)))
        with_p.append(np.linalg.norm(e))
        without.append(np.linalg.norm(_static_run(0.0, tilt, seed)[0]))
    assert 0.9 < np.mean(nees) < 3.5
    assert np.mean(with_p) < 0.75 * np.mean(without)


def test_a_tilted_board_is_pulled_toward_level_by_the_expected_shrinkage():
    """Bayes: with frame information ``1/s_f^2`` and prior ``1/s_p^2`` on a tilt, the
    estimate of a board tilted by ``a`` is ``a s_p^2 / (s_p^2 + s_f^2)`` (noise-free)."""
    f0 = _filter(0.0)
    poses = [_camera(1.5)] * 150
    s_f = np.sqrt(np.linalg.inv(f0.information(np.eye(4), poses))[0, 0])
    s_p = np.radians(0.5)
    a = np.radians(2.0)
    g_t = _tilt(a, 0.0)
    f = _filter(0.5, iterations=4)
    for g in poses:
        f.update(_pixels(g, g_t), g)
    est = np.degrees(np.arctan2(f.pose[2, 1], f.pose[2, 2]))  # tilt about x
    expected = np.degrees(a * s_p**2 / (s_p**2 + s_f**2))
    assert est == pytest.approx(expected, rel=0.1)


def test_level_prior_validation():
    with pytest.raises(ValueError, match="level_prior"):
        TargetFilter(LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=-1.0)
    with pytest.raises(ValueError, match="level_normal"):
        TargetFilter(
            LOCAL_CAMERA, PAPER_MARKER.feature_points, level_prior=0.0, level_normal=(0, 0, 0)
        )


def test_scene_target_tilt():
    level = SceneConfig().target_pose
    g = SceneConfig(target_tilt_deg=(0.3, -0.4)).target_pose
    cos = float(level[:3, 2] @ g[:3, 2])
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))) == pytest.approx(0.5, rel=1e-3)
    np.testing.assert_allclose(g[:3, 3], level[:3, 3])
    with pytest.raises(ValueError, match="target_tilt_deg"):
        SceneConfig(target_tilt_deg=(40.0, 0.0))


@pytest.mark.parametrize(
    ("section", "key", "value"),
    [
        ("ibvs", "target_level_prior_deg", -1.0),
        ("ibvs", "target_level_normal", [0.0, 0.0, 0.0]),
        ("scene", "target_tilt_deg", [45.0, 0.0]),
    ],
)
def test_scenario_keys_are_validated(section, key, value):
    with pytest.raises(ScenarioError, match=f"{section}.{key}"):
        load_scenario("paper-in-fov").with_overrides({section: {key: value}})


def test_scenario_normal_reaches_the_filter():
    """``ibvs.target_level_normal`` and the prior reach the servo's filter (normalized)."""
    from tdacm.sim import build_loop

    sc = load_scenario("paper-in-fov").with_overrides(
        {
            "cameras": {"local_renderer": "analytic", "global_every": 0},
            "ibvs": {"target_level_normal": [0.0, 0.0, -2.0], "target_level_prior_deg": 0.3},
        }
    )
    loop = build_loop(sc, 0).loop
    f = loop.servo.target_filter
    np.testing.assert_allclose(f.level_normal, [0.0, 0.0, -1.0])
    assert f.level_prior == pytest.approx(np.radians(0.3))
    loop.close()

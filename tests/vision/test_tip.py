"""Tip-level mapping: camera twist -> tip twist (adjoint) -> commanded joint rates, with a
kinematic stand-in of the model and with the real coupled model."""

from __future__ import annotations

import numpy as np
import pytest

from tdacm.lie.se3 import expmap, inv_se3, vee
from tdacm.vision import (
    DEFAULT_TIP_CAMERA_MOUNT,
    LOCAL_CAMERA,
    SceneConfig,
    camera_joint_rates,
    camera_to_tip_twist,
    commanded_coordinates,
    tip_camera_mount,
    tip_joint_rates,
)
from tdacm.vision.kinematic import tdacm_servo

SCENE = SceneConfig()
Q_FINAL = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0])  # the paper's final state


def test_adjoint_maps_camera_twist_to_tip_twist():
    """Rigid mount: the body twist of L is Ad(g_C^L) times the body twist of C."""
    rng = np.random.default_rng(0)
    mount = tip_camera_mount(offset=0.03)
    g_c0 = expmap(rng.normal(size=6))
    v_c = rng.normal(size=6)
    h = 1e-6
    g_l = [expmap(s * h * v_c) for s in (-1, 1)]
    g_l = [g_c0 @ e @ inv_se3(mount) for e in g_l]
    g_l0 = g_c0 @ inv_se3(mount)
    v_l = vee(inv_se3(g_l0) @ (g_l[1] - g_l[0]) / (2 * h))
    np.testing.assert_allclose(camera_to_tip_twist(v_c, mount), v_l, atol=1e-7)
    # the default mount has the optical axis on the tip x axis: a spin about the optical
    # axis is a spin about the backbone
    np.testing.assert_allclose(
        camera_to_tip_twist([0, 0, 1, 0, 0, 0]), [1, 0, 0, 0, 0, 0], atol=1e-12
    )


def _check_rates(system, q):
    rng = np.random.default_rng(1)
    idx = commanded_coordinates(system)
    jac = system.tip_jacobian(q)
    qdot_cmd = rng.normal(size=idx.size)
    v = jac[:, idx] @ qdot_cmd  # a reachable tip twist
    qdot = tip_joint_rates(system, q, v)
    np.testing.assert_allclose(qdot[idx], qdot_cmd, atol=1e-8)
    np.testing.assert_allclose(jac @ qdot, v, atol=1e-9)
    return qdot


def test_joint_rates_fake_system(fake_system):
    assert list(commanded_coordinates(fake_system)) == [2, 3, 4, 5, 6, 7]
    q = np.array([0.05, -0.04, 0.3, 0.2, -0.1, 3.2, 0.2, -0.3])
    qdot = _check_rates(fake_system, q)
    assert qdot[0] == 0.0 and qdot[1] == 0.0  # roll and pitch are not commanded
    # "virtual": the Jacobian at zero roll/pitch
    v = np.array([0.1, -0.2, 0.05, 0.3, 0.0, -0.1])
    qv = q.copy()
    qv[:2] = 0.0
    np.testing.assert_allclose(
        tip_joint_rates(fake_system, q, v, jacobian_at="virtual"),
        tip_joint_rates(fake_system, qv, v),
        atol=1e-12,
    )
    # camera-level helper = adjoint + pseudo-inverse
    np.testing.assert_allclose(
        camera_joint_rates(fake_system, q, v),
        tip_joint_rates(fake_system, q, camera_to_tip_twist(v, DEFAULT_TIP_CAMERA_MOUNT)),
    )


def test_fixed_base_commands_all_coordinates():
    class Fixed:
        n = 2
        floating = False

        def tip_jacobian(self, q):
            return np.array([[0, 0], [1, 0], [0, 1], [0, 0], [0, 0.5], [-0.5, 0]], float)

    assert list(commanded_coordinates(Fixed())) == [0, 1]
    qdot = tip_joint_rates(Fixed(), np.zeros(2), [0, 1, 0, 0, 0, -0.5])
    np.testing.assert_allclose(qdot, [1, 0], atol=1e-12)


def test_validation(fake_system):
    q = np.zeros(8)
    with pytest.raises(ValueError, match="q"):
        tip_joint_rates(fake_system, np.zeros(7), np.zeros(6))
    with pytest.raises(ValueError, match="tip_twist"):
        tip_joint_rates(fake_system, q, np.zeros(5))
    with pytest.raises(ValueError, match="commanded"):
        tip_joint_rates(fake_system, q, np.zeros(6), commanded=[0, 9])
    with pytest.raises(ValueError, match="jacobian_at"):
        tip_joint_rates(fake_system, q, np.zeros(6), jacobian_at="somewhere")
    with pytest.raises(ValueError, match="mount"):
        camera_to_tip_twist(np.zeros(6), np.zeros((4, 4)))


@pytest.mark.parametrize("tilt", [(0.0, 0.0), (0.06, -0.04)], ids=["level", "tilted"])
def test_kinematic_arm_servo_fake(fake_system, tilt):
    """IBVS + virtual camera + tip mapping drive the fake TD-ACM to the reference view; with
    the drone held tilted, C_V still converges (to the same yaw, position and shape)."""
    q0 = np.array([*tilt, np.radians(25.0), -0.3, 0.25, 3.8, 0.15, -0.1])
    r = tdacm_servo(
        fake_system,
        q0,
        Q_FINAL,
        SCENE.target_points_world(),
        gain=3.0,
        max_steps=600,
        camera=LOCAL_CAMERA,
    )
    assert r.converged, r
    np.testing.assert_allclose(r.q[2:], Q_FINAL[2:], atol=1e-4)
    np.testing.assert_allclose(r.q[:2], tilt)


def _paper_system():
    tdacm = pytest.importorskip("tdacm")
    if not hasattr(tdacm, "paper_system"):
        pytest.skip("tdacm.paper_system() not available")
    return tdacm.paper_system()


def test_real_system_api_and_rates():
    system = _paper_system()
    assert system.n == 8 and system.floating
    np.testing.assert_allclose(
        tip_camera_mount(system.attachment), DEFAULT_TIP_CAMERA_MOUNT, atol=1e-12
    )
    q = np.array([0.05, -0.04, 0.3, 0.2, -0.1, 3.2, 0.2, -0.3])
    qdot = _check_rates(system, q)
    assert qdot[0] == 0.0 and qdot[1] == 0.0
    # the tip Jacobian agrees with finite differences of the tip pose (the API contract)
    h = 1e-6
    g_inv = inv_se3(system.tip_pose(q))
    for i in range(system.n):
        dq = np.zeros(system.n)
        dq[i] = h
        dg = (system.tip_pose(q + dq) - system.tip_pose(q - dq)) / (2 * h)
        np.testing.assert_allclose(system.tip_jacobian(q)[:, i], vee(g_inv @ dg), atol=1e-6)


@pytest.mark.parametrize("tilt", [(0.0, 0.0), (0.05, 0.03)], ids=["level", "tilted"])
def test_kinematic_arm_servo_real_system(tilt):
    system = _paper_system()
    q0 = np.array([*tilt, np.radians(-30.0), 0.3, -0.2, 3.7, -0.15, 0.12])
    r = tdacm_servo(
        system,
        q0,
        Q_FINAL,
        SCENE.target_points_world(),
        gain=3.0,
        max_steps=600,
        camera=LOCAL_CAMERA,
    )
    assert r.converged, r
    np.testing.assert_allclose(r.q[2:], Q_FINAL[2:], atol=1e-4)

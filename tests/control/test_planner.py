import numpy as np
import pytest

from tdacm import paper_system
from tdacm.control import (
    CubicTrajectory,
    ModeSwitch,
    estimate_target_pose,
    plan_rod_configuration,
    target_in_local_camera,
)
from tdacm.vision import (
    GLOBAL_CAMERA,
    LOCAL_CAMERA,
    PAPER_MARKER,
    PlanarRenderer,
    SceneConfig,
    TargetDetector,
    camera_pose,
    drone_camera_mount,
    tip_camera_mount,
    world_to_camera,
)


def test_cubic_boundary_conditions():
    tr = CubicTrajectory([0.0, 1.0], [1.0, -1.0], 1.0, 3.0)
    q, qd, _ = tr(1.0)
    assert np.allclose(q, [0, 1]) and np.allclose(qd, 0)
    q, qd, _ = tr(3.0)
    assert np.allclose(q, [1, -1]) and np.allclose(qd, 0)
    q, qd, _ = tr(2.0)
    assert np.allclose(q, [0.5, 0.0]) and np.allclose(qd, [0.75, -1.5])
    h = 1e-6
    assert np.allclose((tr(1.7 + h)[0] - tr(1.7 - h)[0]) / (2 * h), tr(1.7)[1], atol=1e-6)


@pytest.fixture(scope="module")
def setup():
    s = paper_system()
    q = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.35, 0.45])
    scene = SceneConfig(box_xy=(0.1, -0.05))
    return s, q, scene


def test_snapshot_pose_and_optimum_on_optical_axis(setup):
    s, q, scene = setup
    tip_mount = tip_camera_mount(s.attachment)
    drone_mount = drone_camera_mount()
    g_cg = camera_pose(s.base_pose(q), drone_mount)
    img = PlanarRenderer(scene).render(GLOBAL_CAMERA, g_cg)
    det = TargetDetector(PAPER_MARKER).detect(img)
    assert det.found
    g_t = estimate_target_pose(det, GLOBAL_CAMERA, PAPER_MARKER)
    true = np.linalg.solve(g_cg, scene.target_pose)
    assert np.linalg.norm(g_t[:3, 3] - true[:3, 3]) < 0.03 * np.linalg.norm(true[:3, 3])
    assert np.allclose(g_t[:3, :3], true[:3, :3], atol=0.05)
    # target outside C_L initially
    g_cl = camera_pose(s.tip_pose(q), tip_mount)
    assert not LOCAL_CAMERA.all_in_fov(world_to_camera(scene.target_points_world(), g_cl))
    p_body = (drone_mount @ g_t[:, 3])[:3]
    plan = plan_rod_configuration(s, p_body, tip_mount, q[6:], z_min=LOCAL_CAMERA.near)
    assert plan.success
    assert np.hypot(*plan.point_local[:2]) < 1e-4 and plan.point_local[2] > LOCAL_CAMERA.near
    # ... and the true target centre lies on C_L's optical axis at the planned strains
    q_new = q.copy()
    q_new[6:] = plan.q_s
    g_cl = camera_pose(s.tip_pose(q_new), tip_mount)
    c = world_to_camera(scene.target_pose[:3, 3], g_cl)[0]
    assert np.hypot(c[0], c[1]) / c[2] < 0.02
    assert LOCAL_CAMERA.all_in_fov(world_to_camera(scene.target_points_world(), g_cl), 20)
    # chain consistency: the planner's prediction equals the real projection for exact input
    p_true = np.linalg.solve(s.base_pose(q), scene.target_pose[:, 3])[:3]
    pred = target_in_local_camera(s, plan.q_s, p_true, tip_mount)
    assert np.allclose(pred, c, atol=1e-9)


def test_mode_switch_margin_and_hysteresis():
    sw = ModeSwitch(LOCAL_CAMERA, margin_px=20, confirm=2, lose=3)
    inside = np.array([[500, 500], [500, 600], [600, 600], [600, 500.0]])
    edge = inside.copy()
    edge[0] = [10, 500]  # within the margin
    assert sw.update(edge) == "recovery"
    assert sw.update(inside) == "recovery"  # needs two consecutive frames
    assert sw.update(edge) == "recovery"
    assert sw.update(inside) == "recovery"
    assert sw.update(inside) == "ibvs"
    assert sw.update(None) == "ibvs"  # a dropped frame does not switch back
    assert sw.update(edge) == "ibvs"
    assert sw.update(None) == "ibvs"
    assert sw.update(None) == "ibvs"
    assert sw.update(None) == "recovery"


def test_plan_jacobian_matches_finite_differences():
    """The planner's ``d r^{C_L} / d q_s`` (``[r^] J_w - J_v``) against central differences."""
    from tdacm.control.planner import _point_and_jacobian

    s = paper_system()
    m = s.model_arrays
    mount_inv = np.linalg.inv(tip_camera_mount(s.attachment))
    p_body = np.array([0.3, -0.2, -1.5])
    qs = np.array([0.3, -0.2])
    p, jac = np.empty(3), np.empty((3, 2))
    args = (m, int(m.rod_steps[0]), int(m.rod_steps[1]), mount_inv, p_body)
    _point_and_jacobian(qs, *args, p, jac)
    h = 1e-6
    for c in range(2):
        e = np.zeros(2)
        e[c] = h
        pp, pm, jj = np.empty(3), np.empty(3), np.empty((3, 2))
        _point_and_jacobian(qs + e, *args, pp, jj)
        _point_and_jacobian(qs - e, *args, pm, jj)
        np.testing.assert_allclose(jac[:, c], (pp - pm) / (2 * h), atol=1e-7)


@pytest.mark.parametrize("rod", [0, 1])
def test_plan_for_either_arm_of_two(rod):
    """The recovery plan of one arm of two (its strains only): the planned strains put the
    target on that arm's C_L optical axis through the full two-arm chain, the other arm's
    strains do not change the plan, and a single-arm robot's plan is unchanged by the rod
    argument's default."""
    from tdacm import dual_paper_system
    from tdacm.control.planner import rod_columns

    s = dual_paper_system()
    tip_mount = tip_camera_mount()
    cols = rod_columns(s, rod)
    assert cols.stop - cols.start == s.n_s // 2
    sign = 1.0 if rod == 0 else -1.0
    p_body = np.array([sign * 0.5, 0.25, -2.0])  # beside the arm, out of its straight view
    plan = plan_rod_configuration(s, p_body, tip_mount, np.zeros(2), z_min=LOCAL_CAMERA.near,
                                  rod=rod)  # fmt: skip
    assert plan.success and np.hypot(*plan.point_local[:2]) < 1e-4
    for other in (0.0, 0.4):  # the other arm bent or not: same point in this arm's camera
        q = np.zeros(s.n)
        q[6:] = other
        q[6 + cols.start : 6 + cols.stop] = plan.q_s
        g_cl = s.base_pose(q) @ np.linalg.solve(s.base_pose(q), s.tip_pose(q, rod)) @ tip_mount
        r = np.linalg.solve(g_cl, s.base_pose(q) @ np.append(p_body, 1.0))[:3]
        assert np.allclose(r, plan.point_local, atol=1e-9)
        assert np.allclose(target_in_local_camera(s, plan.q_s, p_body, tip_mount, rod), r,
                           atol=1e-9)  # fmt: skip

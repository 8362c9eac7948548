"""The cameras' chain (:func:`tdacm.vision.mounts.camera_chain`) gives the same numbers,
bit for bit, as the full recursion :func:`tdacm.system.kernels.chain_jacobian` it shortens
(the pose without the Jacobian, the Jacobian without its rate)."""

import numpy as np

from tdacm.sim.batch import build_batch
from tdacm.sim.scenario import load_scenario
from tdacm.system.kernels import chain_jacobian
from tdacm.vision.mounts import camera_chain

ENGINE = {
    "cameras": {"local_renderer": "analytic", "global_renderer": "planar"},
    "ibvs": {"features": "measured"},
}


def test_pose_and_jacobian_equal_the_full_recursion_bit_for_bit():
    sc = load_scenario("paper-in-fov").with_overrides(ENGINE, "t")
    b = build_batch(sc, [0], duration=0.1)
    m = b.model.plant_model
    rod = b.model.servo.rod[0, 0]  # world 0, arm 0
    lo, hi = rod
    rng = np.random.default_rng(3)
    q0 = b.q0[0]
    for _ in range(20):
        q = q0 + rng.normal(0.0, 0.3, q0.shape)
        g, j, _ = chain_jacobian(
            q, np.zeros_like(q), m.floating, m.g_fixed, m.g_att[0], m.h[lo:hi], m.xi0s[lo:hi],
            m.bs[lo:hi], m.step_col[lo:hi], m.step_nc[lo:hi],
        )  # fmt: skip
        g_pose = np.empty((4, 4))
        camera_chain(q, m, rod, False, g_pose, np.empty((0, 0)))
        g_j, j_j = np.empty((4, 4)), np.empty((6, q.shape[0]))
        camera_chain(q, m, rod, True, g_j, j_j)
        np.testing.assert_array_equal(g_pose, g)
        np.testing.assert_array_equal(g_j, g)
        np.testing.assert_array_equal(j_j, j)
        assert np.any(j != 0.0)

"""Every state the loop can reach ends a period with a named Termination, never an exception:
non-finite commands, a tumbling drone, a diverged estimator; a C_L view whose corners admit no
pose in front of the camera is a missed frame."""

import numpy as np
import pytest

from tdacm.loop import Termination
from tdacm.loop.data import CameraMeasurement, StateEstimate
from tdacm.loop.plant import MAX_TILT_RAD
from tdacm.sim import build_loop, load_scenario
from tdacm.vision.detect import Detection
from tdacm.vision.features import _estimate_depths, estimate_depths

FAST = {"cameras": {"local_renderer": "analytic", "global_renderer": "planar", "global_every": 0}}


@pytest.fixture(scope="module")
def assembly():
    a = build_loop(load_scenario("paper-in-fov").with_overrides(FAST, "test"))
    yield a
    a.loop.close()


def test_non_finite_twist_and_inputs_end_the_period(assembly):
    loop = assembly.loop
    for kw, words in (
        ({"twist": np.array([0, 0, np.nan, 0, 0, 0])}, "twist"),
        ({"u": np.r_[np.full(4, np.inf), np.zeros(4)]}, "actuator command"),
    ):
        loop.reset(assembly.world.q0, assembly.world.qd0)
        st = loop.step(**kw)
        assert st.done and st.termination is Termination.NON_FINITE and words in st.reason
        assert loop.plant.state.t == 0.0  # the plant did not advance on it


def test_a_tumbling_drone_ends_the_run_by_name(assembly):
    loop = assembly.loop
    s = loop.plant.system
    loop.reset(assembly.world.q0, assembly.world.qd0)
    # full thrust on two adjacent rotors, none on the others: the drone rolls over
    u = np.r_[s.base.max_thrust, s.base.max_thrust, 0.0, 0.0, np.zeros(s.n_a)]
    for _ in range(200):
        st = loop.step(u=u)
        if st.done:
            break
    assert st.termination is Termination.TUMBLED, st.reason
    q = loop.plant.state.q
    assert max(abs(q[0]), abs(q[1])) > MAX_TILT_RAD and "tumbled" in st.reason


def test_a_failed_estimate_ends_the_run(assembly):
    loop = assembly.loop
    loop.reset(assembly.world.q0, assembly.world.qd0)
    sensed = loop.sense()
    est = sensed.estimate
    from dataclasses import replace

    bad = replace(sensed, estimate=StateEstimate(est.t, est.q, est.qd, failure="diverged"))
    st = loop.act(bad)
    assert st.termination is Termination.ESTIMATOR_FAILED and st.reason == "diverged"
    nan_q = est.q.copy()
    nan_q[3] = np.nan
    st = loop.act(replace(sensed, estimate=StateEstimate(est.t, nan_q, est.qd)))
    assert st.termination is Termination.ESTIMATOR_FAILED and "non-finite" in st.reason


def test_the_ekf_divergence_becomes_the_estimate_failure():
    from tdacm.estimation import EstimatorDiverged

    sc = load_scenario("paper-in-fov").with_overrides(
        {**FAST, "estimation": {"source": "estimated"}}, "test"
    )
    a = build_loop(sc)
    loop = a.loop
    try:
        loop.reset()
        block = loop.estimator

        def diverge(*args, **kw):
            raise EstimatorDiverged("estimator diverged (non-finite state)")

        block.filter.step = diverge
        st = loop.step()
        assert st.termination is Termination.ESTIMATOR_FAILED
        assert st.reason == "estimator diverged (non-finite state)"
    finally:
        loop.close()


def test_a_singular_innovation_covariance_is_the_filter_diverging():
    """Found by the fuzz campaign (90 % dropout, 7 periods of latency, random thrusts): the
    EKF's solve with H P H^T + R raised LinAlgError out of the run. A broken covariance (NaN:
    what a diverged filter leaves) must end the run as the filter's failure."""
    from tdacm.estimation import ekf_step as ES

    sc = load_scenario("ground-test-a").with_overrides(
        {**FAST, "estimation": {"source": "estimated"}}, "test"
    )
    loop = build_loop(sc).loop
    try:
        loop.reset()
        f = loop.estimator.filter
        f.state.p[ES.ekf_latest(f.state)] = np.nan
        st = loop.step()
        assert st.termination is Termination.ESTIMATOR_FAILED
        assert st.reason == ES.DIVERGENCE[ES.NONFINITE_INNOVATION]
        assert "singular innovation covariance" in st.reason
    finally:
        loop.close()


def test_a_view_without_a_pose_is_a_missed_frame(assembly):
    loop = assembly.loop
    obj = np.asarray(assembly.world.target.feature_points, float)
    # normalized corners as 50 px of noise can leave them: IPPE's best pose has the target
    # behind the camera (found by drawing noisy squares)
    bad = np.array([[-0.005, -0.045], [-0.087, 0.004], [0.027, 0.061], [0.0, -0.06]])
    z, why = _estimate_depths(bad, obj)
    assert z is None and why == "pose estimation put the target behind the camera"
    with pytest.raises(ValueError, match="behind the camera"):
        estimate_depths(bad, obj)  # the public function still says why
    cam = loop.perception.local_camera
    m = CameraMeasurement(0.0, Detection(True, cam.denormalize(bad), (), {}))
    assert not loop.perception.local(m).found  # rejected: a missed frame
    good = np.array([[-0.1, -0.1], [-0.1, 0.1], [0.1, 0.1], [0.1, -0.1]])
    m = CameraMeasurement(0.0, Detection(True, cam.denormalize(good), (), {}))
    assert loop.perception.local(m).found


def test_a_view_with_no_image_in_the_virtual_camera_is_named_by_the_servo(assembly):
    from tdacm.vision.virtual import BehindVirtualCamera

    loop = assembly.loop
    loop.reset(assembly.world.q0, assembly.world.qd0)
    sensed = loop.sense()
    assert sensed.view.found
    q = sensed.estimate.q.copy()
    q[0] = 2.0  # rolled past 90 degrees: the target lies behind C_V (the loop's BEHIND_CAMERA)
    with pytest.raises(BehindVirtualCamera):
        loop.servo.observe(sensed.view, q)


def test_a_fronto_parallel_reference_view_gives_its_depths():
    """Found by the fuzz campaign: a robot whose rendered reference view at desired.q is
    seen exactly head-on (the homography's Jacobian a scaled rotation at the principal point),
    where OpenCV's IPPE returned NaN and the build fell back to the analytic projection. The
    compiled IPPE handles the case: the detected reference gives the true depths (to the
    renderer's corner error, 0.1 %)."""
    over = {
        "robot": {
            "rod": {"length": 0.9509902317318857, "diameter": 0.0016063272948239437,
                    "density": 7923.595896729291, "youngs_modulus": 74484656894.81564,
                    "damping": 93.35160822851604, "tip_mass": 0.007353004564123378},
            "tendons": {"radius": 0.0074356603069228675, "max_tension": 38.48347719331806},
            "attachment": {"offset": 0.058226870849051364},
            "drone": {"mass": 0.530639555126165, "max_thrust": 16.50294737127488},
        },
        "cameras": {"local_renderer": "planar", "global_renderer": "planar", "global_every": 0},
    }  # fmt: skip
    from tdacm.vision.target_filter import reference_from_pose

    a = build_loop(load_scenario("paper-in-fov").with_overrides(over, "test"))
    try:
        loop, w = a.loop, a.world
        det, _ = loop.sensors.local.ideal(w.q_star)
        z = estimate_depths(loop.perception.local_camera.normalize(det.points),
                            w.target.feature_points)  # fmt: skip
        g_c = loop.sensors.local.pose(w.q_star)
        _, z_true = reference_from_pose(w.target, w.scene.target_pose, g_c)
        np.testing.assert_allclose(z, z_true, rtol=1e-3)
        assert np.all(np.isfinite(loop.servo.desired_points))
    finally:
        a.loop.close()


def test_a_target_estimate_whose_corners_coincide_gives_no_prediction(assembly):
    """Found by the fuzz campaign (156 px of noise, estimated state, random thrusts): the
    robust servo's target estimate went so far that the predicted corners coincided, and the
    features raised. The prediction is then invalid: the target is not seen this period."""
    servo = assembly.loop.servo
    loop = assembly.loop
    loop.reset(assembly.world.q0, assembly.world.qd0)
    q = assembly.world.q0
    far = np.eye(4)
    far[:3, 3] = [0.0, 0.0, -1e13]  # far below the drone: the four corners in one point
    servo.target_pose = far
    pv = servo.predicted_view(servo.servo_camera_pose(q))
    assert not pv.valid
    servo.target_pose = assembly.world.scene.target_pose.copy()
    assert servo.predicted_view(servo.servo_camera_pose(q)).valid

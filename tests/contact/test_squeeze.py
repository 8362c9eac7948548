"""The two-arm squeeze (dual-squeeze, tdacm.loop.touch_arms): both probes on one ball, each
arm's normal force from the tendons, solved together; the squeeze's summary and campaign."""

from pathlib import Path

import numpy as np
import pytest

from tdacm.estimation.contact_force import TipForceEstimator, normal_forces_of
from tdacm.loop.touch import CONTACT_CODE
from tdacm.loop.touch_arms import (
    arm_contact_forces,
    balance_step,
    squeeze_force_loops,
    squeeze_reset,
    squeeze_transitions,
)
from tdacm.sim import Simulation, load_scenario
from tdacm.sim.assemble import build_loop, build_world
from tdacm.sim.scenario import ScenarioError
from tdacm.system.contact import contact_state, probe_offset

SPECS = Path(__file__).resolve().parents[2] / "examples" / "campaigns"


def _squeeze():
    return load_scenario("dual-squeeze")


def test_the_probes_touch_the_ball_at_the_contact_pose():
    """The scenario's geometry: at [desired] q both probes' spheres sit on the ball (within
    0.1 mm) on its opposite sides, each probe's axis through the ball's centre (the contact
    normal along the probe), and each marker faces its camera from the contact point."""
    sc = _squeeze()
    w = build_world(sc)
    s = w.robot.system
    ball = sc.config.scene.obstacles[0]
    centre, radius = np.asarray(ball.position), ball.radius
    ends = []
    for arm, scene in zip(w.robot.arms, w.scenes, strict=True):
        g = s.tip_pose(w.q_star, arm.rod) @ arm.tip_mount
        end = g[:3, 3] + arm.probe_length * g[:3, 2]
        ends.append(end)
        assert np.linalg.norm(end - centre) - radius - 0.01 == pytest.approx(0.0, abs=1e-4)
        to_centre = (centre - end) / np.linalg.norm(centre - end)
        assert to_centre @ g[:3, 2] > 1 - 1e-6  # the axis passes through the centre
        assert scene.target_pose[:3, 2] @ g[:3, 2] > 1 - 1e-6  # the marker faces the camera
    assert ends[0][0] == pytest.approx(-ends[1][0], abs=1e-9) and ends[0][0] > 0.1


def _estimators(sc):
    a = build_loop(sc)
    s = a.world.robot.system
    model = a.model
    off = probe_offset(a.world.robot.tip_mount, a.world.robot.probe_length)
    return s, a, [TipForceEstimator(model, "all", input_sigma=0.02, offset=off, rod=k)
                  for k in range(2)]  # fmt: skip


def test_forces_of_two_arms_are_solved_together():
    """A residual made of two known normal forces, one on each arm's probe: the joint solve
    returns both (exact), where arm 0's estimate alone would count arm 1's force in the drone's
    rows; with one estimator it is the single-arm normal_force_of."""
    s, a, est = _estimators(_squeeze())
    q = a.world.q_star.copy()
    normals = [
        -(s.tip_pose(q, k) @ arm.tip_mount)[:3, 2] for k, arm in enumerate(a.world.robot.arms)
    ]
    f_true = np.array([0.31, 0.27])
    r = sum(e._a(q) @ (n * f) for e, n, f in zip(est, normals, f_true, strict=True))
    cov = np.eye(s.n) * 1e-4
    f, sigma = normal_forces_of(est, q, r, normals, cov)
    np.testing.assert_allclose(f, f_true, rtol=1e-10)
    assert np.all(np.isfinite(sigma)) and np.all(sigma > 0)
    alone = est[0].normal_force_of(q, r, normals[0], cov)[0]
    assert abs(alone - f_true[0]) > 0.01  # the drone's rows see arm 1's force too
    one = normal_forces_of(est[:1], q, r, normals[:1], cov)
    assert one[0][0] == pytest.approx(alone, rel=1e-12)


def test_arm_contact_forces_split_the_contact_kernel():
    """The per-arm forces (rod capsules and tip sphere of each rod) sum to the kernel's total,
    and with one probe pressed into the ball only that arm is loaded."""
    a = build_loop(_squeeze())
    s, plant = a.world.robot.system, a.loop.plant
    q = a.world.q_star.copy()
    q[6] += 0.004  # arm 0 bends 4 mrad further in: its probe presses the ball
    q[8] += 0.004  # arm 1 bends less: its probe leaves it
    per = arm_contact_forces(s, plant.contact)(q, np.zeros(s.n))
    total = contact_state(s, q, np.zeros(s.n), plant.contact).total
    np.testing.assert_allclose(per.sum(axis=0), total, atol=1e-14)
    assert np.linalg.norm(per[0]) > 0.05 and np.linalg.norm(per[1]) == 0.0


def test_dual_squeeze_reaches_contact_on_both_arms():
    """Short (2.5 s, no model error): started 1 cm above the contact pose, both probes touch
    the ball, the forces and the state stay finite, and each arm's estimate follows its true
    force (measured: touching from 2.0 s, the estimates within 0.02 N)."""
    sc = _squeeze()
    q0 = list(sc.config.desired.q)
    q0[5] += 0.01
    sc = sc.with_overrides({"initial": {"q": q0}, "duration": 2.5, "model": {"perturbation": 0.0},
                            "touch": {"standoff": 0.01, "dwell": 0.1}})  # fmt: skip
    arrays, s = Simulation(sc, seed=1).run(None)
    assert not s["terminated"], s["termination_reason"]
    assert np.all(np.isfinite(arrays["q"])) and np.all(np.isfinite(arrays["u"]))
    ft, fh = arrays["force_true_arms"], arrays["force_hat_arms"]
    assert np.all(np.isfinite(ft))
    late = arrays["t"] >= 2.2
    assert (ft[late] > 0.0).all(), ft[late]  # both arms touching
    assert (arrays["touch_phase_arms"][late] == 1).all()  # both in the contact phase
    assert np.all(np.isfinite(fh[late])) and np.abs(fh[late] - ft[late]).max() < 0.04
    assert s["max_contact_force"] < sc.config.scene.contact.force_limit


def _servo_at_contact():
    """The squeeze's servo at the contact pose with every arm pressing, its interaction
    matrices those of the reference views."""
    a = build_loop(_squeeze())
    servo, q = a.loop.servo, a.world.q_star.copy()
    servo.reset(q)
    so = servo.squeeze_out
    for k, arm in enumerate(servo.arms):
        so.weights[k] = arm.ibvs.interaction(arm.desired_points, arm.desired_depths)
    so.pressing[:] = True
    return servo, q


def _axial(servo, q, dq):
    """Each arm's camera displacement along its optical axis for the joint displacement
    ``dq``."""
    return np.array([(arm._ad_mount_inv @ arm.task_jacobian(q) @ dq)[5] for arm in servo.arms])


def _balance_step(servo, q, a, forces, dt, qd=None):
    """The compiled balance step on the servo's records with the forces used ``forces``."""
    st = servo.squeeze_state
    st.f_used[:] = forces
    qd = np.zeros_like(q) if qd is None else qd
    balance_step(servo.squeeze, st, servo.params, servo.arms[0].params, servo.arms[0].state,
                 servo.arms[0]._m, dt, q, qd, a, servo.squeeze_out.weights)  # fmt: skip


def _force_loops(servo, q, forces, dt, t=0.0):
    """The compiled force loops on the servo's records with the forces used ``forces``."""
    st = servo.squeeze_state
    st.f_used[:] = forces
    squeeze_force_loops(servo.law, servo.squeeze, st, servo.params, servo.arms[0].state,
                        servo.arms[0]._m, t, dt, q, np.zeros_like(q),
                        servo.squeeze_out.weights)  # fmt: skip


def test_balance_direction_moves_one_probe_in_and_the_other_out():
    """The balance direction b: camera 0 half a metre in along its axis, camera 1 half a
    metre out (the axial rows weighted in a least squares against the views' features: met to
    1.2 %, measured), the drone's x and both rods' in-plane bend; the squeeze
    direction a moves both in by one metre each. A force on arm 0 above the mean moves its
    camera back, arm 1's forward, by balance_gain times the difference, and leaves the mean
    loop's offset along a as it is."""
    servo, q = _servo_at_contact()
    (b,) = servo.balance_directions(q)
    np.testing.assert_allclose(_axial(servo, q, b), [0.5, -0.5], rtol=0.02)
    # at the symmetric contact pose: the drone's x and the same in-plane bend of both rods
    # (measured: x -1.55 m, strains -1.68 /m per unit), nothing else
    assert abs(b[3]) > 1.0 and b[6] == pytest.approx(b[8], rel=1e-9)
    assert np.abs(np.delete(b, [3, 6, 8])).max() < 1e-9
    a = servo.squeeze_direction(q)
    np.testing.assert_allclose(_axial(servo, q, a), [1.0, 1.0], rtol=0.02)
    lead, tc = servo.arms[0].state, servo.touch
    lead.q_d[:] = q
    _balance_step(servo, q, a, [0.35, 0.25], 0.02)
    dq = lead.q_d - q
    assert abs(a @ dq) < 1e-12 * np.linalg.norm(a) * np.linalg.norm(dq)
    bo = b - a * (a @ b) / (a @ a)  # the direction the step uses: b made orthogonal to a
    expected = tc.balance_gain * (0.30 - 0.35)
    np.testing.assert_allclose(dq, bo * expected, rtol=1e-9, atol=1e-15)
    ax = _axial(servo, q, dq)
    assert ax[0] < 0 < ax[1]


def test_the_force_loops_engage_at_the_first_touch():
    """From the first arm's touch (the other probe still off the ball, its force zero) the mean
    loop pushes along a on the mean force error, bumplessly (its first period moves the
    reference by the integral's increment only, force_integral times the error times dt),
    and the balance
    loop moves the arm still off in (its camera forward, the touched one back); before any
    touch neither runs."""
    servo, q = _servo_at_contact()
    lead, tc, st = servo.arms[0].state, servo.touch, servo.squeeze_state
    st.phase[:] = CONTACT_CODE
    lead.q_d[:], lead.qd_d[:] = q, 0.0
    forces = [0.15, 0.0]
    _force_loops(servo, q, forces, 0.02)
    assert not st.engaged[0] and np.abs(lead.q_d - q).max() == 0.0  # nobody down yet
    st.touch_t[:] = [10.0, np.nan]  # arm 0 down, arm 1 not yet
    _force_loops(servo, q, forces, 0.02)
    assert st.engaged[0]
    a = servo.squeeze_direction(q)
    (b,) = servo.balance_directions(q)
    bo = b - a * (a @ b) / (a @ a)
    err = tc.force - np.mean(forces)
    expected = a * (tc.force_integral * err * 0.02)
    expected += bo * (tc.balance_gain * (np.mean(forces) - forces[0]))
    np.testing.assert_allclose(lead.q_d - q, expected, rtol=1e-9, atol=1e-15)
    ax = _axial(servo, q, lead.q_d - q)
    assert ax[1] > ax[0] > 0  # both move in, the arm still off the more


def test_squeeze_refusals():
    """One probe for every arm (the kernels carry one), and something to touch."""
    sc = _squeeze()
    arms = [dict(a) for a in sc.data["robot"]["arms"]]
    arms[1]["tip"] = {"probe_length": 0.25}
    with pytest.raises(ScenarioError, match=r"robot\.arms\[1\]\.tip\.probe_length"):
        build_loop(sc.with_overrides({"robot": {"arms": arms}}))
    with pytest.raises(ScenarioError, match=r"\[\[scene\.obstacles\]\]"):
        build_loop(sc.with_overrides({"scene": {"obstacles": []}}))


@pytest.mark.slow
def test_dual_squeeze_campaign_holds_in_90_percent(tmp_path):
    """The shipped held-out spec (docs/contact.md, "The squeeze"): at least 45 of 50 runs
    hold both arms' force within 20 % RMS with both image errors at or below 0.01, none over
    the force limit. Slow: a 50-run campaign of 20 s runs."""
    from tdacm.campaign import read_results, run_campaign

    report = run_campaign(SPECS / "dual-squeeze-50.toml", tmp_path / "c", workers=2,
                          progress=False)  # fmt: skip
    df = read_results(tmp_path / "c")
    assert len(df) == 50 and report["errors"] == 0
    assert int(df["success"].sum()) >= 45, df["hold_force_rms_rel"].describe()
    assert (df["max_contact_force"] < 1.5).all()


def test_balance_damping_reads_the_drone_velocity():
    """On a floating base the balance loop's damping reads the mode's velocity from the
    drone's coordinates only: the strain rates (the estimate's noisiest, differenced encoders)
    move nothing, and a drone velocity along x gives ``-c (dt / tau) v_x / b_x`` along the
    balance direction at the first period (the filtered rate starts from rest)."""
    servo, q = _servo_at_contact()
    lead, tc, st = servo.arms[0].state, servo.touch, servo.squeeze_state
    a = servo.squeeze_direction(q)
    (b,) = servo.balance_directions(q)
    bo = b - a * (a @ b) / (a @ a)
    lead.q_d[:] = q
    qd = np.zeros_like(q)
    qd[6:] = [0.02, -0.02, 0.02, -0.02]  # 0.02 /m/s on every strain rate, as the EKF's noise
    _balance_step(servo, q, a, [0.3, 0.3], 0.02, qd)
    assert np.abs(lead.q_d - q).max() == 0.0
    st.rate_on[0] = st.balance_on[0] = False
    qd = np.zeros_like(q)
    qd[3] = 0.01  # the drone moving along x at 1 cm/s
    _balance_step(servo, q, a, [0.3, 0.3], 0.02, qd)
    rate = bo[3] * 0.01 / bo[3] ** 2
    expected = -tc.balance_damping * (0.02 / tc.balance_filter) * rate
    np.testing.assert_allclose(lead.q_d - q, bo * expected, rtol=1e-9, atol=1e-15)


def _transitions(servo, t, forces):
    """The squeeze's phase changes at ``t`` with the filtered forces ``forces``."""
    return squeeze_transitions(servo.law, servo.squeeze, servo.refs, servo.squeeze_state,
                               servo._outs, t, np.asarray(forces, float))  # fmt: skip


def _landed(servo, t, errors):
    """Both probes down at ``t`` (the filtered estimates at 0.12 N), their landings' task
    image errors ``errors``."""
    servo.squeeze_state.phase[:] = CONTACT_CODE
    _transitions(servo, t, [0.12, 0.12])
    servo.squeeze_state.task_err[:] = errors


def test_a_squeeze_landing_off_the_marker_is_unloaded_and_landed_again():
    """The squeeze's landing check (docs/contact.md, "The squeeze on estimates"): ``settle`` s
    after the last touch, one arm's task image error above ``land_rmse`` starts the unloading
    (the mean loop's desired force ramped toward zero at ``force / unload_time``, both arms);
    once it is down to ``detect_force`` every arm goes back to its approach (the standoff
    view) and the squeeze lands again; a landing on both markers starts the hold, and the
    ``max_landings``-th is held wherever it is."""
    servo, _ = _servo_at_contact()
    tc, st = servo.touch, servo.squeeze_state
    squeeze_reset(st)
    _landed(servo, 10.0, [0.009, 0.003])  # arm 0 off the marker
    assert servo.landings == 1
    t = 10.0 + tc.settle
    _transitions(servo, t, [0.3, 0.3])
    assert servo.phases == ["contact", "contact"] and st.unload_t[0] == t
    assert servo.desired_force(t + 0.5 * tc.unload_time) == pytest.approx(0.5 * tc.force)
    assert servo.desired_force(t + 2.0 * tc.unload_time) == 0.0
    leave = t + tc.unload_time * (1.0 - tc.detect_force / tc.force)  # down to detect_force
    _transitions(servo, leave - 0.02, [0.12, 0.12])
    assert servo.phases == ["contact", "contact"] and st.unload_t[0] == t  # still unloading
    t = leave
    _transitions(servo, t, [0.12, 0.12])
    assert servo.phases == ["approach", "approach"] and np.isnan(st.touch_t).all()
    assert servo.desired_force(t) == tc.force and not st.engaged[0]
    _landed(servo, t + 10.0, [0.004, 0.006])  # both on their markers
    assert servo.landings == 2
    _transitions(servo, t + 10.0 + tc.settle, [0.3, 0.3])
    assert servo.phases == ["hold", "hold"]
    assert st.hold_end[0] == pytest.approx(t + 10.0 + tc.settle + tc.hold_time)
    # the last landing is held wherever it is
    squeeze_reset(st)
    st.landings[0] = tc.max_landings - 1
    _landed(servo, 0.0, [0.02, 0.02])
    _transitions(servo, tc.settle, [0.3, 0.3])
    assert servo.phases == ["hold", "hold"] and servo.landings == tc.max_landings

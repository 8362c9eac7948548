"""The hold judged on the task (tdacm.loop.touch, docs/contact.md "The hold judged on the
task"): the task's image error in the tip camera C_L, the reference snapshot in C_L, the pinned
law and the servo's switch into and out of it."""

import numpy as np
import pytest

from tdacm.loop.data import ForceReading, PlantState, StateEstimate
from tdacm.loop.servo import normalized_rmse
from tdacm.loop.touch import (
    CONTACT,
    HOLD,
    RELEASE,
    is_pinned,
    pinned_error,
    task_image_error,
)
from tdacm.sim import load_scenario
from tdacm.sim.assemble import build_loop
from tdacm.sim.blocks import truth_of
from tdacm.vision.target_filter import target_in_camera


def _noise_free(**over):
    sc = load_scenario("touch-target")
    return sc.with_overrides({"sensors": {"pixel_noise": 0.0}, **over})


def test_task_image_error_is_where_the_probe_aims_on_the_marker():
    """A constructed view: the 20 cm marker facing C_L at the contact depth (0.305 m) and the
    camera moved sideways by d. Every corner moves by d / Z in the normalized image, so the
    task's image error is d / Z exactly (the probe's end, on C_L's axis, is d off the point it
    aims at in the reference); a rotation about the axis by a small angle a moves the corners
    by a |p_k|, and no point's depth enters."""
    half, z = 0.1, 0.305
    obj = np.array([[-half, -half, 0.0], [-half, half, 0.0], [half, half, 0.0], [half, -half, 0.0]])
    ref = obj[:, :2] / z
    for d in (0.0005, 0.0015, 0.003):
        moved = (obj[:, :2] - [d, 0.0]) / z
        assert task_image_error(moved, ref) == pytest.approx(d / z, rel=1e-12)
    a = 0.004
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    turned = ref @ rot.T
    expect = np.sqrt(np.mean(np.sum((turned - ref) ** 2, axis=1)))
    assert task_image_error(turned, ref) == pytest.approx(expect, rel=1e-12)
    assert task_image_error(turned, ref) == pytest.approx(2 * np.sin(a / 2) * half * np.sqrt(2) / z)
    assert np.isnan(task_image_error(None, ref))  # no detection: no value


def test_reference_snapshot_in_c_l_is_the_view_at_the_desired_pose():
    """The C_L reference is the tip camera's own view at [desired] q (the true projection, to
    the detector's rounding); at touch-target's level contact pose it is the C_V reference;
    with the desired pose tilted by 5 mrad the two differ by the tilt's image (about 4.5 per
    radian at this depth), and C_L's is still the view from the real camera."""
    a = build_loop(_noise_free())
    servo, world = a.loop.servo, a.world
    true_local = truth_of(world, a.loop.sensors.local, virtual=False)
    assert servo.local_points == pytest.approx(true_local(world.q_star)[0], abs=1e-12)
    assert servo.local_points == pytest.approx(servo.desired_points, abs=1e-12)
    assert a.loop.log.local_reference is not None
    assert np.array_equal(a.loop.log.local_reference, servo.local_points)
    q = list(load_scenario("touch-target").data["desired"]["q"])
    q[1] = 0.005
    b = build_loop(_noise_free(desired={"q": q}))
    sb = b.loop.servo
    assert sb.local_points == pytest.approx(true_local(np.asarray(q))[0], abs=1e-12)
    shift = normalized_rmse(sb.local_points, sb.desired_points)
    assert 4.0 * 0.005 < shift < 5.0 * 0.005


def test_pinned_error_rows():
    """C_L's attitude rows, the lean (C_V's centroid error minus C_L's) on the centroid rows,
    zero distance; without C_V the lean is zero."""
    task = np.array([0.01, -0.02, 0.03, 0.004, -0.005, 0.2])
    virtual = np.array([0.5, 0.6, 0.7, 0.014, 0.001, 0.3])
    assert pinned_error(task, virtual).tolist() == pytest.approx(
        [0.01, -0.02, 0.03, 0.010, 0.006, 0.0], abs=1e-15
    )
    assert pinned_error(task, None).tolist() == [0.01, -0.02, 0.03, 0.0, 0.0, 0.0]
    assert is_pinned(CONTACT, True, "local") and is_pinned(HOLD, True, "local")
    assert not is_pinned(CONTACT, False, "local")  # moving in: C_V
    assert not is_pinned(RELEASE, True, "local") and not is_pinned(HOLD, True, "virtual")


def _drive(servo, loop, q, t, force, dt=0.02):
    """One servo period at the (true, noise-free) configuration ``q`` with a force reading."""
    m = loop.sensors.local.measure(PlantState(t, q, np.zeros(len(q))))
    view = loop.perception.local(m)
    est = StateEstimate(t, q, np.zeros(len(q)))
    return servo.step(t, dt, view, None, est, force=ForceReading(t, force, 0.01, None, True)), view


def _settle_target(loop, servo, q_star) -> float:
    """Fuse 1.2 s of frames from the standoff (the target filter initializes there, as in a
    run's approach); returns the time reached."""
    q = q_star.copy()
    q[5] += 0.1
    loop.reset(q)
    t = 0.0
    for _ in range(60):
        _drive(servo, loop, q, t, 0.0)
        t += 0.02
    assert servo.target_pose is not None
    return t


def test_switch_into_and_out_of_the_task_view():
    """The drone tilted by 3 mrad, the probe near the contact pose. Moving in (contact, no
    touch yet) the servo reads C_V: its points are C_V's prediction and its RMSE C_V's. At the
    first touch (the filtered force reaching detect_force) it switches to C_L: its points are
    C_L's prediction, its RMSE the task's image error (measured: equal to the detected points'
    to 1e-9 without noise), the command re-arms the safety monitor, the twist is the pinned
    law's; the two views differ by the tilt's image (about 0.013 here). At the release it is
    back on C_V's standoff view, re-arming again. The landing, 0.014 off the marker (the
    tilt's image in C_L), is held (``max_landings = 1``): the landing check would lift it, and
    with the force reading held at 0.3 N the lift would never end (tests/contact/
    test_landing.py checks the landings)."""
    a = build_loop(_noise_free(touch={"max_landings": 1}))
    loop, servo = a.loop, a.loop.servo
    tc = servo.touch
    q = a.world.q_star.copy()
    q[0] = 0.003  # roll: C_V and C_L differ by the tilt's image
    q[5] += 0.002  # 2 mm above the contact pose
    t = _settle_target(loop, servo, a.world.q_star)
    servo.phase = CONTACT  # moving in (the standoff dwell is the approach's, tested elsewhere)
    cmd, view = _drive(servo, loop, q, t, 0.0)
    ps = servo.predicted()
    assert cmd.points == pytest.approx(ps.points, abs=1e-15)
    assert cmd.rmse == pytest.approx(normalized_rmse(ps.points, servo.desired_points), abs=1e-15)
    assert cmd.twist[5] == pytest.approx(tc.touch_speed, rel=1e-9)  # moving in at touch speed
    switched = []
    for _ in range(20):  # the estimate above detect_force: the filter reaches it in a few periods
        t += 0.02
        cmd, view = _drive(servo, loop, q, t, 0.3)
        switched.append(cmd.phase_changed)
        if servo.touched:
            break
    assert servo.touched and switched[-1] and not any(switched[:-1])
    lv = servo.local_view(q)
    assert cmd.points == pytest.approx(lv.points, abs=1e-15)
    assert cmd.rmse == pytest.approx(task_image_error(lv.points, servo.local_points), abs=1e-15)
    assert cmd.rmse_measured == pytest.approx(
        task_image_error(view.points, servo.local_points), abs=1e-15
    )
    assert cmd.rmse == pytest.approx(cmd.rmse_measured, abs=1e-9)  # noise-free
    e = pinned_error(lv.error, servo.predicted().error)
    v = servo.local_ibvs.twist(lv.points, lv.depths, error=e)
    assert cmd.twist[:5] == pytest.approx(v[:5], abs=1e-15) and cmd.twist[5] == 0.0
    c_v = normalized_rmse(servo.predicted().points, servo.desired_points)
    assert abs(c_v - cmd.rmse) > 0.01  # the tilt's image: C_V moved, C_L did not
    t += 0.02
    cmd, _ = _drive(servo, loop, q, t, 0.3)
    assert not cmd.phase_changed and cmd.phase == CONTACT
    t_end = servo.touch_state.touch_t[0] + tc.settle + tc.hold_time
    while servo.phase != RELEASE:
        t += 0.02
        cmd, _ = _drive(servo, loop, q, t, 0.3)
        assert t < t_end + 0.1
    assert cmd.phase_changed
    ps = servo.predicted()
    assert cmd.points == pytest.approx(ps.points, abs=1e-15)
    assert cmd.rmse == pytest.approx(normalized_rmse(ps.points, servo.standoff_points), abs=1e-15)


def test_virtual_contact_view_never_switches():
    """``touch.contact_view = "virtual"``: the servo reads C_V while pressing too."""
    a = build_loop(_noise_free(touch={"contact_view": "virtual"}))
    loop, servo = a.loop, a.loop.servo
    q = a.world.q_star.copy()
    q[0] = 0.003
    t = _settle_target(loop, servo, a.world.q_star)
    servo.phase = CONTACT
    for _ in range(20):
        t += 0.02
        cmd, _ = _drive(servo, loop, q, t, 0.3)
        assert not cmd.phase_changed
    assert servo.touched
    assert cmd.points == pytest.approx(servo.predicted().points, abs=1e-15)


def test_target_in_camera_matches_the_truth():
    """The C_L prediction's geometry (the target filter's projection) is the logger's truth in
    C_L for the true target pose: the task view the servo reads and the one it is judged on
    are the same function of the camera pose."""
    a = build_loop(_noise_free())
    world = a.world
    q = world.q_star.copy()
    q[[0, 3]] = [0.002, 0.001]
    g_c = a.loop.servo.local_camera_pose(q)
    r = target_in_camera(world.target.feature_points, g_c, world.scene.target_pose)
    truth = truth_of(world, a.loop.sensors.local, virtual=False)(q)[0]
    assert r[:, :2] / r[:, 2:3] == pytest.approx(truth, abs=1e-12)


def test_touch_target_on_estimates_holds_within_the_task_rule():
    """On the EKF's state (default sensors, the scenario's 10 % model error), started 0.19 m
    above the contact pose: the probe lands on the marker, the servo switches to C_L at the
    touch, and the 2 s hold meets the campaigns' rule (the true force within 20 % RMS, the
    task's image error at or below 0.01 throughout, not ended). The hold starts once the force
    estimate has settled (``force_settled``). Measured (seed 4): hold from 12.98 s, force RMS
    error 3.2 % (15.0 % with the hold from ``settle``, 11.98 s), task image error 0.0064 (the
    servo's own, C_L's prediction from the estimate, 0.0074), largest force 0.46 N."""
    from tdacm.sim import Simulation

    sc = load_scenario("touch-target")
    q0 = list(sc.data["initial"]["q"])
    q0[5] = 2.0
    sc = sc.with_overrides(
        {"initial": {"q": q0}, "touch": {"hold_time": 2.0}, "duration": 15.5,
         "estimation": {"source": "estimated"}}
    )  # fmt: skip
    arrays, s = Simulation(sc, seed=4).run(None)
    assert not s["terminated"], s["termination_reason"]
    assert s["hold_duration"] == pytest.approx(2.0, abs=0.011)
    assert s["hold_force_rms_rel"] <= 0.1  # the settled force (0.15 from settle)
    assert s["hold_image_error_max"] <= 0.01
    assert s["hold_image_error_true_max"] <= 0.01
    assert s["landings"] >= 1 and s["max_contact_force"] < sc.config.scene.contact.force_limit
    hold = arrays["touch_phase"] == 2
    # the servo's error during the hold is the task view's (C_L), not C_V's
    assert np.nanmax(np.abs(arrays["rmse"][hold] - arrays["rmse_local"][hold])) < 0.005

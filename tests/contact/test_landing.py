"""Landing on the marker (tdacm.loop.touch, docs/contact.md "Landing on the marker"): the
landing check at ``settle`` and the aim of the next landing corrected by the offset the lifted
ones repeated (:func:`~tdacm.loop.touch.aim_shift`)."""

import numpy as np
import pytest

from tdacm.loop.touch import CONTACT, HOLD, aim_shift
from tdacm.sim.assemble import build_loop
from tdacm.vision.ibvs import IBVSController

from .test_touch_task import _drive, _noise_free, _settle_target


def test_aim_shift_is_the_shrunk_mean_of_the_landings():
    """k / (k + 1) times the mean of the k samples: half the first landing's offset, two
    thirds of the mean of two; a bias repeated by every landing is approached as k grows,
    a scatter of zero mean is not followed."""
    assert aim_shift([]).tolist() == [0.0, 0.0]
    assert aim_shift([[0.006, -0.004]]) == pytest.approx([0.003, -0.002], abs=1e-15)
    assert aim_shift([[0.006, -0.004], [0.003, 0.002]]) == pytest.approx(
        [0.003, -0.000666666666666667], abs=1e-15
    )
    bias = np.array([0.005, -0.003])
    assert aim_shift([bias] * 9) == pytest.approx(0.9 * bias, abs=1e-15)
    assert aim_shift([[0.004, 0.0], [-0.004, 0.0]]) == pytest.approx([0.0, 0.0], abs=1e-15)


def _touch(servo, loop, q, t):
    """Press (force reading 0.3 N) until the servo counts the touch; returns the time."""
    for _ in range(20):
        t += 0.02
        _drive(servo, loop, q, t, 0.3)
        if servo.touched:
            return t
    raise AssertionError("no touch")


def _landed(dx, correction=True):
    """The probe landed ``dx`` m beside the contact pose along the drone's x (noise-free,
    ``touch.land_correction`` as given); returns the loop, the servo, the pose and the time of
    the touch."""
    a = build_loop(_noise_free(touch={"land_correction": correction}))
    loop, servo = a.loop, a.loop.servo
    q = a.world.q_star.copy()
    q[3] += dx
    t = _settle_target(loop, servo, a.world.q_star)
    servo.phase = CONTACT
    return loop, servo, q, _touch(servo, loop, q, t)


def test_landing_on_the_marker_is_held_without_an_aim_shift():
    """1 mm beside the marker's centre (task image error 1 / 305 = 0.0033 < land_rmse 0.007):
    the hold starts settle s after the touch; nothing was lifted, the aim is not shifted."""
    loop, servo, q, t0 = _landed(0.001)
    t = t0
    while servo.phase == CONTACT:
        t += 0.02
        _drive(servo, loop, q, t, 0.3)
        assert not servo.lifting
    assert servo.phase == HOLD and t - t0 == pytest.approx(servo.touch.settle, abs=1e-9)
    assert servo.touch_state.task_err[0] == pytest.approx(0.001 / 0.305, rel=0.02)
    assert servo.aim.tolist() == [0.0, 0.0] and servo.landings == 1


def test_a_lifted_landing_shifts_the_next_aim_by_half_its_offset():
    """3 mm beside the centre (0.0098 > land_rmse): lifted at settle. The detected C_L
    centroid is 3 / 305 = 0.0098 off along one image axis (the probe's end 3 mm off the
    marker's centre), and the next landing is aimed half of that the other way: moving in,
    the servo's C_V error is the one to the reference's points less the shift (an
    independent IBVS law on the shifted points gives the same twist)."""
    loop, servo, q, t0 = _landed(0.003)
    t = t0
    while not servo.lifting:
        t += 0.02
        _drive(servo, loop, q, t, 0.3)
    assert t - t0 == pytest.approx(servo.touch.settle, abs=1e-9)
    assert servo.touch_state.aim_count[0] == 1
    sample = servo.touch_state.aim_total.copy()
    assert np.hypot(*sample) == pytest.approx(0.003 / 0.305, rel=0.02)
    assert min(abs(sample)) < 1e-4  # along one image axis
    assert servo.aim == pytest.approx(0.5 * sample, abs=1e-15)
    q[3] -= 0.003  # back over the marker's centre, moving in (the estimate still pressed)
    t += 0.02
    cmd, _ = _drive(servo, loop, q, t, 0.3)
    ps = servo.predicted()
    law = {"gain": servo.ibvs.gain, "floor": servo.ibvs.floor}
    shifted = IBVSController(servo.desired_points - servo.aim, servo.desired_depths, **law)
    e = shifted.error(ps.points)
    e[5] = 0.0
    assert e[3:5] == pytest.approx(ps.error[3:5] + servo.aim, abs=1e-12)
    v = servo.ibvs.twist(ps.points, ps.depths, error=e)
    assert cmd.twist[:5] == pytest.approx(v[:5], abs=1e-12)
    assert cmd.twist[5] == -servo.touch.approach_speed  # lifting


def test_without_the_correction_the_aim_stays():
    """``touch.land_correction = false`` (the default): a lifted landing leaves the aim where
    it was."""
    loop, servo, q, t0 = _landed(0.003, correction=False)
    t = t0
    while not servo.lifting:
        t += 0.02
        _drive(servo, loop, q, t, 0.3)
    assert servo.aim.tolist() == [0.0, 0.0] and servo.touch_state.aim_count[0] == 0


def test_force_settled_band_and_wait():
    """The hold may start when the filtered estimate is within settle_band (10 %) of the
    desired force, or settle_wait (1 s) after settle whatever it reads."""
    from tdacm.loop.config import TouchConfig
    from tdacm.loop.touch import TouchLaw, force_settled

    tc = TouchLaw.from_config(TouchConfig(enabled=True))
    assert force_settled(0.32, tc.settle, tc) and force_settled(0.28, tc.settle, tc)
    assert not force_settled(0.34, tc.settle, tc) and not force_settled(0.26, tc.settle, tc)
    assert not force_settled(0.45, tc.settle + 0.98, tc)
    assert force_settled(0.45, tc.settle + tc.settle_wait, tc)


def test_the_hold_waits_for_the_force_to_settle():
    """A landing kept at settle with the estimate still at 0.45 N (the impact's overshoot):
    no hold until the filtered estimate is within 10 % of 0.3 N; held at 0.45 N throughout,
    the hold starts settle + settle_wait after the touch."""
    for late, expect_wait in ((0.3, None), (0.45, 1.0)):
        loop, servo, q, t0 = _landed(0.001)
        tc = servo.touch
        t = t0
        while servo.phase == CONTACT:
            t += 0.02
            reading = 0.45 if t - t0 < tc.settle + 0.2 - 1e-9 else late
            _drive(servo, loop, q, t, reading)
            assert t - t0 < tc.settle + tc.settle_wait + 0.01
        assert servo.phase == HOLD and servo.landings == 1
        if expect_wait is None:  # the estimate back at 0.3 N from settle + 0.2 s
            assert tc.settle + 0.2 < t - t0 < tc.settle + 0.5
            assert abs(servo.touch_state.f[0] - tc.force) <= tc.settle_band * tc.force
        else:
            assert t - t0 == pytest.approx(tc.settle + expect_wait, abs=1e-9)

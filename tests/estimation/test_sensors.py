"""Sensor models: schedule, latency, dropout, noise statistics, physics of each reading."""

import numpy as np
import pytest

from tdacm import paper_system
from tdacm.estimation import (
    DronePoseSensor,
    EncoderConfig,
    Imu,
    ImuConfig,
    PoseSensorConfig,
    SensorSuite,
    SensorSuiteConfig,
    TendonEncoders,
)
from tdacm.lie.euler import rot_zyx
from tdacm.system import kernels as K

Q = np.array([0.05, -0.04, 0.3, 0.2, -0.1, 3.0, 0.25, -0.35])


@pytest.fixture(scope="module")
def system():
    return paper_system()


def test_schedule_latency_and_capture_time():
    cfg = PoseSensorConfig(rate_hz=25.0, latency=0.04, position_noise=0.0, attitude_noise=0.0)
    s = DronePoseSensor(cfg, np.random.default_rng(0))
    got = []
    for k in range(11):
        t = 0.02 * k
        m = s.sample(t, Q, np.zeros(8))
        got.append(None if m is None else (round(t, 3), round(m.t, 3)))
    delivered = [g for g in got if g is not None]
    # captures at 0, 0.04, 0.08, ... delivered 0.04 s later, stamped with the capture time
    assert delivered == [(0.04, 0.0), (0.08, 0.04), (0.12, 0.08), (0.16, 0.12), (0.2, 0.16)]
    m = s.sample(0.24, Q, np.zeros(8))
    np.testing.assert_allclose(m.position, Q[3:6])
    np.testing.assert_allclose(m.rotation, rot_zyx(*Q[:3]), atol=1e-15)


def test_pose_noise_statistics_and_dropout():
    cfg = PoseSensorConfig(latency=0.0, position_noise=0.003, attitude_noise=0.005, dropout=0.3)
    s = DronePoseSensor(cfg, np.random.default_rng(1))
    r0 = rot_zyx(*Q[:3])
    dp, dr, lost = [], [], 0
    for k in range(4000):
        m = s.sample(0.02 * k, Q, np.zeros(8))
        if m is None:
            lost += 1
            continue
        dp.append(m.position - Q[3:6])
        e = r0.T @ m.rotation
        dr.append([e[2, 1], e[0, 2], e[1, 0]])  # small rotation vector
    assert lost / 4000 == pytest.approx(0.3, abs=0.03)
    np.testing.assert_allclose(np.std(dp, axis=0), 0.003, rtol=0.06)
    np.testing.assert_allclose(np.std(dr, axis=0), 0.005, rtol=0.06)
    assert np.all(np.abs(np.mean(dp, axis=0)) < 2e-4)


def test_imu_specific_force_and_body_rate(system):
    """Hovering at rest the accelerometer reads +g along body z (specific force); the gyro the
    body rate ``T(phi, theta) Phi_dot``."""
    cfg = ImuConfig(gyro_noise=0, gyro_bias=0, accel_noise=0, accel_bias=0)
    imu = Imu(cfg, system.loads.gravity, np.random.default_rng(0))
    q = np.zeros(8)
    q[5] = 3.0
    m = imu.sample(0.0, q, np.zeros(8), np.zeros(8))
    np.testing.assert_allclose(m.accel, [0, 0, 9.81], atol=1e-12)
    # tilted and accelerating: f = R^T (a - g)
    qd = np.array([0.1, -0.2, 0.3, 0, 0, 0, 0, 0])
    qdd = np.array([0, 0, 0, 1.0, -2.0, 0.5, 0, 0])
    m = imu.sample(0.02, Q, qd, qdd)
    r = rot_zyx(*Q[:3])
    np.testing.assert_allclose(m.accel, r.T @ (qdd[3:6] - system.loads.gravity), atol=1e-12)
    # body rate from the base Jacobian of the model (twist of the drone in its frame)
    _, jb, _ = K.base_state(Q, qd, True, np.eye(4), 8)
    np.testing.assert_allclose(m.gyro, (jb @ qd)[:3], atol=1e-12)


def test_imu_biases_are_seeded_and_constant(system):
    cfg = ImuConfig(gyro_noise=0.0, accel_noise=0.0)
    a = Imu(cfg, system.loads.gravity, np.random.default_rng(5))
    b = Imu(cfg, system.loads.gravity, np.random.default_rng(5))
    np.testing.assert_array_equal(a.gyro_bias, b.gyro_bias)
    m1 = a.sample(0.0, Q, np.zeros(8), np.zeros(8))
    m2 = a.sample(0.02, Q, np.zeros(8), np.zeros(8))
    np.testing.assert_allclose(m1.gyro, a.gyro_bias, atol=1e-15)
    np.testing.assert_allclose(m1.gyro, m2.gyro, atol=1e-15)
    assert np.linalg.norm(a.gyro_bias) > 0


def test_encoders_measure_tendon_length_change(system):
    cfg = EncoderConfig(resolution=0.0, noise=0.0)
    enc = TendonEncoders(cfg, system, np.random.default_rng(0))
    m = enc.sample(0.0, Q, np.zeros(8))
    expected = system.tendon_lengths(Q) - system.tendon_lengths(np.zeros(8))
    np.testing.assert_allclose(m.delta_length, expected, atol=1e-15)
    # parallel tendons on a constant-curvature rod: dl = -L (B_s^T q_s) exactly (linear map)
    np.testing.assert_allclose(m.delta_length, -system.tendon_matrix(Q).T @ Q[6:], atol=1e-14)
    # pulled tendons shorten: an antagonistic pair changes by opposite amounts
    assert m.delta_length[0] == pytest.approx(-m.delta_length[2])


def test_encoder_quantization_and_bias(system):
    cfg = EncoderConfig(resolution=1e-5, noise=0.0, bias=1e-3)
    enc = TendonEncoders(cfg, system, np.random.default_rng(3))
    m = enc.sample(0.0, Q, np.zeros(8))
    counts = m.delta_length / 1e-5
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    exact = system.tendon_lengths(Q) - system.tendon_lengths(np.zeros(8)) + enc.bias
    assert np.all(np.abs(m.delta_length - exact) <= 0.5e-5 + 1e-12)
    assert np.all(np.abs(enc.bias) > 0)


def test_suite_from_scenario_section_and_validation(system):
    cfg = SensorSuiteConfig.from_section(
        {"pose_latency": 0.0, "encoder_noise": 1e-6, "pixel_noise": 1.0}
    )
    assert cfg.pose.latency == 0.0 and cfg.encoders.noise == 1e-6
    with pytest.raises(ValueError, match="sensors.pose_dropout"):
        SensorSuiteConfig.from_section({"pose_dropout": 1.0})
    with pytest.raises(ValueError, match="sensors.gyro_noise"):
        SensorSuiteConfig.from_section({"gyro_noise": -1.0})
    suite = SensorSuite(system, cfg, seed=7)
    out = suite.sample(0.0, Q, np.zeros(8), np.zeros(8))
    assert {type(m).__name__ for m in out} == {
        "PoseMeasurement",
        "ImuMeasurement",
        "EncoderMeasurement",
    }
    # reproducible from the seed
    again = SensorSuite(system, cfg, seed=7).sample(0.0, Q, np.zeros(8), np.zeros(8))
    for a, b in zip(out, again, strict=True):
        for f in a.__dataclass_fields__:
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))


def test_fixed_base_has_encoders_only():
    held = np.zeros(8)
    held[5] = 3.0
    fixed = paper_system(fixed_base_pose=paper_system().base_pose(held))
    suite = SensorSuite(fixed, seed=0)
    out = suite.sample(0.0, np.array([0.1, -0.2]), np.zeros(2))
    assert [type(m).__name__ for m in out] == ["EncoderMeasurement"]

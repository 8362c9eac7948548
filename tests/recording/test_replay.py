"""Offline replay of an MCAP recording through perception, the servo's features and the EKF."""

from __future__ import annotations

import numpy as np
import pytest

from tdacm.cli import main
from tdacm.recording import export_run, read_mcap, replay
from tdacm.sim import Simulation, load_scenario

# measured features: the servo's features are a function of the detected points and q
FAST = (
    '[cameras]\nlocal_renderer = "analytic"\nglobal_renderer = "planar"\n'
    '[ibvs]\nfeatures = "measured"\n'
)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A real 0.5 s run of ground-test-a exported as MCAP: (scenario file, run arrays, mcap)."""
    tmp = tmp_path_factory.mktemp("replay")
    (tmp / "fast.toml").write_text('extends = "ground-test-a"\n' + FAST)
    sc = load_scenario(tmp / "fast.toml")
    Simulation(sc, duration=0.5).run(tmp / "run")
    with np.load(tmp / "run" / "timeseries.npz") as f:
        arrays = {k: f[k] for k in f.files}
    return tmp / "fast.toml", arrays, export_run(tmp / "run", tmp / "run.mcap")


def test_replayed_features_equal_the_logged_ones(recorded):
    scenario, a, path = recorded
    res = replay(read_mcap(path), scenario, estimate=False)
    assert not res.estimated
    np.testing.assert_allclose(res.t, a["t"], atol=1e-9)
    assert res.detected.all() and np.isfinite(a["features"]).all()
    np.testing.assert_array_equal(res.q_hat, a["q"])  # the recorded strains, bit for bit
    # the normalized points go back to pixels and through perception again: 1e-12 level
    np.testing.assert_allclose(res.features, a["features"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(res.feature_error, a["feature_error"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(res.rmse, a["rmse"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.points, a["points_virtual"], rtol=0, atol=1e-12)


def test_ekf_replay_on_the_recorded_encoders_tracks_the_strains(recorded):
    """The tendon path lengths of the export as encoders (no noise, no quantization) and the
    recorded tensions as the input: the EKF's strains follow the recorded ones."""
    scenario, a, path = recorded
    res = replay(read_mcap(path), scenario)
    assert res.estimated
    err = np.abs(res.q_hat - a["q"]).max()
    assert err < 1e-4, err  # strains ~0.1-0.2 1/m (measured 1.2e-6)
    assert np.isfinite(res.features).all()


def test_cli_replay_recording(recorded, tmp_path, capsys):
    scenario, a, path = recorded
    argv = ["replay-recording", str(path), "--scenario", str(scenario), "--state", "recorded"]
    assert main(argv + ["--out", str(tmp_path / "r")]) == 0
    with np.load(tmp_path / "r" / "replay.npz") as f:
        np.testing.assert_allclose(f["rmse"], a["rmse"], rtol=0, atol=1e-12)
    capsys.readouterr()
    assert main(argv[:2] + ["--scenario", "no-such", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "--scenario" in err[0], err
    assert main(argv[:2] + ["--scenario", str(scenario), "--topic-map", str(tmp_path / "none.toml"),
                 "--out", str(tmp_path / "x")]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--topic-map" in err[0], err


def _flying_run(tmp, extra=""):
    f = tmp / "flying.toml"
    f.write_text('extends = "paper-in-fov"\n' + FAST + extra)
    Simulation(load_scenario(f), duration=0.3).run(tmp / "run")
    with np.load(tmp / "run" / "timeseries.npz") as d:
        arrays = {k: d[k] for k in d.files}
    return f, arrays, read_mcap(export_run(tmp / "run", tmp / "run.mcap"))


def test_flying_base_replay_recovers_q_from_the_drone_pose(tmp_path):
    """Floating base: q's Euler angles come back from the recorded drone pose (quaternions) and
    the virtual camera's features (eq. (18)) equal the logged ones to rounding."""
    f, a, sig = _flying_run(tmp_path)
    res = replay(sig, f, estimate=False)
    np.testing.assert_allclose(res.q_hat, a["q"], rtol=0, atol=1e-14)
    np.testing.assert_allclose(res.features, a["features"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.rmse, a["rmse"], rtol=0, atol=1e-12)


def test_estimated_run_replays_to_estimates_close_to_the_logged_ones(tmp_path):
    """An EKF run (noisy pose and encoders): the replay's EKF fuses the recorded (noise-free)
    drone pose and tendon lengths, so its estimate differs from the logged q_hat by about the
    logged estimate's own error."""
    f, a, sig = _flying_run(tmp_path, '[estimation]\nsource = "estimated"\n')
    res = replay(sig, f)
    assert res.estimated
    logged_err = np.abs(a["q_hat"] - a["q"]).max(0)
    diff = np.abs(res.q_hat - a["q_hat"]).max(0)
    assert np.all(logged_err < 0.01) and np.all(diff < 0.01), (diff, logged_err)
    assert np.all(diff < 1.5 * logged_err + 1e-3), (diff, logged_err)
    assert np.abs(res.q_hat - a["q"]).max() < 1e-3  # noise-free measurements: near the truth

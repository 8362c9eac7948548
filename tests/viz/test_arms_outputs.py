"""The outputs of a robot with two arms (``dual-in-fov``, 0.1 s): the per-arm series, the
figures per arm, the video with every arm's C_L, the 3-D replay with both arms' cameras and
targets, and the Rerun recording with both rods and C_L images."""

import numpy as np
import pytest

from tdacm.sim import Simulation, load_scenario
from tdacm.viz.video import TILE, CaptionedFrames


@pytest.fixture(scope="module")
def dual(tmp_path_factory):
    out = tmp_path_factory.mktemp("dual")
    cfg = out / "cfg.toml"
    cfg.write_text('[cameras]\nglobal_every = 0\nglobal_renderer = "planar"\n')
    sim = Simulation(load_scenario("dual-in-fov", cfg), duration=0.1, video=True,
                     frame_composer=CaptionedFrames())  # fmt: skip
    sim.run(out / "run")
    return out / "run", sim


def _geometry(run_dir):
    from tdacm.sim.outputs import load_run
    from tdacm.viz._scene import geometry

    arrays, _, scenario = load_run(run_dir)
    return arrays, geometry(scenario)


def test_the_log_has_each_arms_series_and_arm_0s_match_the_single_arm_ones(dual):
    run_dir, _ = dual
    a = dict(np.load(run_dir / "timeseries.npz"))
    T = len(a["t"])
    assert a["points_arms"].shape == (T, 2, 4, 2) and a["twist_arms"].shape == (T, 2, 6)
    assert a["points_local_arms"].shape == (T, 2, 4, 2)
    assert np.array_equal(a["points_arms"][:, 0], a["points_virtual"], equal_nan=True)
    assert np.array_equal(a["points_local_arms"][:, 0], a["points_local"], equal_nan=True)
    assert np.array_equal(a["twist_arms"][:, 0], a["twist"], equal_nan=True)
    assert np.all(np.isfinite(a["points_arms"][:, 1]))  # arm 1 sees its marker (in fov)
    import json

    cols = [c["name"] for c in json.loads((run_dir / "timeseries.json").read_text())["columns"]]
    assert "x1_V_arm1" in cols and "v_z_arm1" in cols and "y4_L_arm0" in cols


def test_each_arms_true_points_are_the_loggers(dual):
    """The outputs' arm geometry (each arm's tip camera, mount and marker) gives the logger's
    true image error of every arm; arm 1's servo points are its true points up to the
    detection (no pixel noise in the scenario)."""
    from tdacm.loop.servo import normalized_rmse

    run_dir, _ = dual
    a, g = _geometry(run_dir)
    assert len(g.arms) == 2 and g.arms[1].rod == 1
    for k in range(len(a["t"])):
        q = a["q"][k]
        r0 = normalized_rmse(g.servo_points(q, 0), a["desired_points"])
        assert r0 == pytest.approx(a["rmse_true_arms"][k, 0], rel=1e-9, abs=1e-12)
        assert np.abs(g.servo_points(q, 1) - a["points_arms"][k, 1]).max() < 5e-3
    # the two arms' cameras are different (arms at +-0.2 m): the geometry is per arm
    assert np.abs(g.local_pose(a["q"][0], 0)[:3, 3] - g.local_pose(a["q"][0], 1)[:3, 3]).max() > 0.3


def test_figures_are_per_arm(dual):
    import matplotlib.image as mpimg

    from tdacm.viz import plot_run_dir

    run_dir, _ = dual
    paths = plot_run_dir(run_dir, formats=("png",), snapshot_at=(0.0, 0.1),
                         kinds=("features", "feature_error", "camera_twist", "snapshots"))  # fmt: skip
    names = {p.stem: p for p in paths}
    assert set(names) == {"features", "feature_error", "camera_twist", "snapshots"}
    one = mpimg.imread(names["snapshots"])
    # snapshots: one row of C_L frames per arm (2.9 inch a row at 110 dpi)
    assert one.shape[0] > 2 * 2.9 * 110 * 0.9
    # features: an image panel per arm and the error panel (4.4 inch each)
    assert mpimg.imread(names["features"]).shape[1] > 3 * 4.4 * 110 * 0.9


def test_the_video_shows_every_arms_camera(dual):
    _, sim = dual
    frames = sim.result.frames
    assert frames and frames[0].shape[1] == 3 * TILE  # C_L arm 0 | C_G | C_L arm 1
    # arm 1's tile is not arm 0's (another camera, another marker)
    assert np.abs(frames[0][:, :TILE].astype(int) - frames[0][:, 2 * TILE :].astype(int)).max() > 0


def test_the_replay_draws_both_arms_cameras_and_targets(dual):
    from tdacm.viz import replay_frames

    run_dir, _ = dual
    a, g = _geometry(run_dir)
    q = a["q"][:1]
    both = replay_frames(g.system, q, size=(240, 200), arms=g.arms)[0]
    first = replay_frames(g.system, q, size=(240, 200), arms=g.arms[:1])[0]
    assert np.abs(both.astype(int) - first.astype(int)).max() > 0


def test_rerun_has_both_rods_and_cameras(dual, tmp_path):
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from tdacm.viz.rerun_log import record_run

    run_dir, _ = dual
    rrd = record_run(run_dir, tmp_path / "x.rrd", image_size=64, image_every=3)
    summary = RrdReader(rrd).stream().collect().summary()
    rows = {ln.split()[0] for ln in summary.splitlines()}
    for entity in ("/world/rod0", "/world/rod1", "/world/C_L0/image", "/world/C_L1/image",
                   "/world/C_L1/image/desired", "/world/target1", "/world/box1",
                   "/plots/rmse_arms", "/world/C_G/image"):  # fmt: skip
        assert entity in rows, (entity, summary)

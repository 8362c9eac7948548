"""3-D replay (GIF/MP4), `tdacm plot` and the Rerun recording of a run folder, through the CLI."""

import numpy as np
import pytest
from PIL import Image

from tdacm.cli import main
from tdacm.sim import run_scenario
from tdacm.viz import plot_run_dir, replay_frames, write_animation
from tdacm.viz.replay import playback_plan


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("replay")
    cfg = out / "cfg.toml"
    cfg.write_text('[cameras]\nglobal_every = 0\nglobal_renderer = "planar"\n')
    run_scenario("paper-in-fov", out=out / "run", config=cfg, duration=0.1)  # the data
    plot_run_dir(out / "run")  # its figures
    return out / "run"


def test_replay_of_a_run_folder(run_dir, capsys):
    assert main(["replay", str(run_dir), "--max-frames", "3"]) == 0
    gif = run_dir / "replay.gif"
    err = capsys.readouterr().err
    assert "3-D replay written to" in err and "replay" in err and "3/3" in err  # progress line
    with Image.open(gif) as im:
        assert im.n_frames == 3 and im.size == (640, 520)
    mp4 = write_animation([np.zeros((32, 32, 3), np.uint8)] * 3, run_dir / "a.mp4")
    assert mp4.stat().st_size > 0


def test_playback_is_real_time_by_default():
    stride, fps, speed = playback_plan(10.0, 501)  # a 10 s run logged at 50 Hz
    assert speed == pytest.approx(1.0, rel=0.05) and 10 <= fps <= 20
    stride, fps, speed = playback_plan(10.0, 501, max_frames=60)  # fewer frames: slower fps
    assert speed == pytest.approx(1.0, rel=0.05) and fps < 20
    stride, _, speed = playback_plan(10.0, 501, fps=20, max_frames=60)  # both fixed: stated
    # each frame shows `stride` periods of 20 ms for 1/20 s
    assert speed == pytest.approx(stride * 0.02 * 20) and speed > 3


def test_frames_show_the_arm_moving():
    import tdacm
    from tdacm.vision import SceneConfig

    system = tdacm.paper_system()
    q0 = np.array([0, 0, 0, 0, 0, 3.0, 0.0, 0.0])
    q1 = np.array([0, 0, 0, 0, 0, 3.0, 0.8, 0.0])
    frames = replay_frames(system, [q0, q1], size=(200, 160), scene=SceneConfig())
    assert len(frames) == 2 and frames[0].shape == (160, 200, 3)
    assert np.abs(frames[0].astype(int) - frames[1].astype(int)).sum() > 0


def test_plot_command_regenerates_figures(run_dir, capsys):
    (run_dir / "snapshots.png").unlink()
    before = (run_dir / "features.png").stat().st_mtime_ns
    assert main(["plot", str(run_dir), "--formats", "png", "--kinds", "snapshots"]) == 0
    assert (run_dir / "snapshots.png").stat().st_size > 0
    assert (run_dir / "features.png").stat().st_mtime_ns == before  # only the kind asked for
    assert "1 figure file written" in capsys.readouterr().err
    assert main(["plot", str(run_dir), "--kinds", "nope"]) == 2
    assert "--kinds" in capsys.readouterr().err


def test_rerun_recording_reads_back(run_dir, capsys):
    from rerun.chunk import RrdReader

    rrd = run_dir / "x.rrd"
    assert main(["replay", str(run_dir), "--rerun", str(rrd)]) == 0
    summary = RrdReader(rrd).stream().collect().summary()
    rows = {ln.split()[0]: ln for ln in summary.splitlines()}
    for entity in ("/world/rod", "/world/drone", "/world/target", "/world/C_L/image",
                   "/world/C_G/image", "/world/C_L/image/detected", "/world/C_L/image/desired",
                   "/plots/rmse", "/plots/feature_error", "/plots/camera_twist",
                   "/plots/strains", "/plots/actuation"):  # fmt: skip
        assert entity in rows, (entity, summary)
    assert "rows=6" in rows["/world/rod"] and "sim_time" in rows["/world/rod"]
    assert "sim_time" in rows["/plots/rmse"]
    assert "Rerun recording written" in capsys.readouterr().err
    # the RMSE series read back equals the stored one, on the simulated-time timeline
    stored = np.load(run_dir / "timeseries.npz")
    for ch in RrdReader(rrd).stream():
        if ch.entity_path == "/plots/rmse" and not ch.is_static:
            rb = ch.to_record_batch()
            vals = np.array([v[0] for v in rb.column("Scalars:scalars").to_pylist()], float)
            times = [x.total_seconds() for x in rb.column("sim_time").to_pylist()]
    assert np.allclose(vals, stored["rmse"], equal_nan=True)
    assert np.allclose(times, stored["t"])

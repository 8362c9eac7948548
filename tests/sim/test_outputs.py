"""The run folder: self-contained (scenario.toml), every NPZ field in the CSV with a units
sidecar, stale files of a previous run removed, captioned H.264 video."""

import json
import subprocess

import numpy as np
import pytest

from tdacm.cli import main
from tdacm.sim import load_scenario
from tdacm.sim.outputs import clear_run_outputs
from tdacm.viz.figures import KINDS


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    cfg = out / "cfg.toml"
    cfg.write_text('[cameras]\nglobal_every = 0\nglobal_renderer = "planar"\n')
    args = ["run", "paper-in-fov", "--out", str(out / "r"), "--config", str(cfg)]
    assert main([*args, "--duration", "0.1", "--video"]) == 0  # data, figures and video
    return out / "r"


def test_run_folder_lists_every_output(run_dir):
    for name in ("summary.json", "scenario.toml", "timeseries.npz", "timeseries.csv",
                 "timeseries.json", "scene.png", "video.mp4"):  # fmt: skip
        assert (run_dir / name).stat().st_size > 0, name
    for kind in KINDS:
        # estimated state (tests/estimation); [touch]; several arms (tests/loop/test_arms.py)
        if kind in ("estimation", "contact", "arms"):
            continue
        for ext in ("png", "pdf"):
            assert (run_dir / f"{kind}.{ext}").stat().st_size > 0, kind


def test_scenario_toml_reloads_to_the_same_data(run_dir):
    stored = load_scenario(run_dir / "scenario.toml")
    cfg = run_dir.parent / "cfg.toml"
    assert stored.data == load_scenario("paper-in-fov", cfg).data


def test_csv_has_every_npz_field_with_units(run_dir):
    npz = np.load(run_dir / "timeseries.npz")
    side = json.loads((run_dir / "timeseries.json").read_text())
    header = (run_dir / "timeseries.csv").read_text().splitlines()[0].split(",")
    table = np.loadtxt(run_dir / "timeseries.csv", delimiter=",", skiprows=1)
    assert [c["name"] for c in side["columns"]] == header
    series = {c["series"] for c in side["columns"]}
    per_step = {k for k in npz.files if npz[k].shape[:1] == npz["t"].shape}
    assert per_step == series  # qd_d, q_ref, delta_hat and both point sets included
    assert {"qd_d", "q_ref", "delta_hat", "points_local", "points_virtual"} <= series
    for c in side["columns"]:
        assert c["unit"] and c["unit"] != "?" and c["meaning"], c
    units = {c["name"]: c["unit"] for c in side["columns"]}
    assert units["z"] == "m" and units["psi"] == "rad" and units["q_s1"] == "1/m"
    assert units["dz"] == "m/s" and units["T1"] == "N" and units["w_x"] == "rad/s"
    # values: the CSV columns equal the NPZ components
    j = header.index("q_s2_d")
    assert np.allclose(table[:, j], npz["q_d"][:, 7], rtol=1e-7, atol=1e-12)
    k = header.index("x4_L")
    assert np.allclose(table[:, k], npz["points_local"][:, 3, 0], rtol=1e-7, equal_nan=True)
    assert np.array_equal(npz["q_star"], [0, 0, 0, 0, 0, 3.0, 0, 0])


def test_video_is_h264_with_captions(run_dir):
    import cv2
    import imageio_ffmpeg

    r = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-i", str(run_dir / "video.mp4")],
                       capture_output=True, text=True)  # fmt: skip
    assert "Video: h264" in r.stderr
    cap = cv2.VideoCapture(str(run_dir / "video.mp4"))
    ok, frame = cap.read()
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    assert ok and n == 6 and frame.shape[1] == 1000
    assert frame[:28].std() > 5 and frame[-30:].std() > 5  # caption bars hold text


def test_rewriting_a_folder_removes_the_previous_run(tmp_path):
    out = tmp_path / "r"
    out.mkdir()
    for name in ("video.mp4", "replay.gif", "features.png", "summary.json"):
        (out / name).write_text("old")
    (out / "notes.txt").write_text("mine")
    removed = clear_run_outputs(out, keep=())
    assert sorted(removed) == ["features.png", "replay.gif", "summary.json", "video.mp4"]
    assert (out / "notes.txt").read_text() == "mine"


def test_cli_rerun_into_same_out_leaves_no_stale_video(tmp_path, capsys):
    from tdacm.cli import main

    cfg = tmp_path / "cfg.toml"
    cfg.write_text('[cameras]\nglobal_every = 0\nglobal_renderer = "planar"\n')
    args = ["run", "ground-test-a", "--duration", "0.04", "--out", str(tmp_path / "o"),
            "--config", str(cfg)]  # fmt: skip
    assert main([*args, "--video"]) == 0
    assert (tmp_path / "o" / "video.mp4").is_file()
    assert main(args) == 0
    assert not (tmp_path / "o" / "video.mp4").exists()
    assert "removed" in capsys.readouterr().err

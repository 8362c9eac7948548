"""``tdacm`` commands end in a documented exit code with one line, never a traceback: noisy
cameras run to their end with every output, an outcome exits 1, bad run folders and ``--out``
paths exit 2, a robot that cannot fly is rejected, Ctrl-C during a compilation exits 130."""

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tdacm import cli
from tdacm.cli import main
from tdacm.loop import Termination
from tdacm.sim.outputs import RUN_FILES

ROOT = Path(__file__).resolve().parents[1]
FAST = '[cameras]\nlocal_renderer = "analytic"\nglobal_renderer = "planar"\nglobal_every = 0\n'


def _run(tmp_path, name, text, duration="0.4", scenario="paper-in-fov"):
    cfg = tmp_path / f"{name}.toml"
    cfg.write_text(FAST + text)
    out = tmp_path / name
    code = main(["-q", "run", scenario, "--config", str(cfg), "--duration", duration,
                 "--out", str(out)])  # fmt: skip
    return code, out


@pytest.mark.parametrize("noise", [20, 100, 1000])
def test_noisy_camera_runs_to_its_end_and_writes_every_output(tmp_path, capsys, noise):
    code, out = _run(tmp_path, f"noise{noise}", f"[sensors]\npixel_noise = {noise}\n")
    summary = json.loads(capsys.readouterr().out)
    assert code == (1 if summary["terminated"] else 0)
    if summary["terminated"]:  # an outcome, named
        assert summary["termination"] in {str(t) for t in Termination}
    else:
        assert summary["duration"] == pytest.approx(0.4)
    for name in ("summary.json", "scenario.toml", "timeseries.npz", "timeseries.csv",
                 "timeseries.json", "features.png", "actuation.png"):  # fmt: skip
        assert (out / name).is_file(), name
    assert set(RUN_FILES) >= {"summary.json", "timeseries.npz"}


def test_a_run_stopped_by_the_safety_monitor_exits_1_with_its_outputs(tmp_path, capsys):
    # a monitor that fires on any growth at all, with noise to make the error grow
    code, out = _run(
        tmp_path, "safety",
        "[sensors]\npixel_noise = 3\n[ibvs]\nfeatures = \"measured\"\n"
        "[safety]\ngrowth_limit = 1e-6\nmin_increase = 0\ngrace = 0\n",
    )  # fmt: skip
    summary = json.loads(capsys.readouterr().out)
    assert code == 1 and summary["termination"] == "safety"
    assert summary["termination_reason"].startswith("safety monitor")
    assert (out / "timeseries.npz").is_file() and (out / "features.png").is_file()


def test_a_drone_that_cannot_lift_the_robot_is_rejected(tmp_path, capsys):
    cfg = tmp_path / "heavy.toml"
    cfg.write_text("[robot.drone]\nmass = 50.0\nmax_thrust = 15.0\n")
    assert main(["run", "paper-in-fov", "--config", str(cfg), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:")
    assert "robot.drone.max_thrust" in err[0] and "robot.drone.mass" in err[0]
    assert not (tmp_path / "o").exists()


def test_the_paper_drone_and_the_custom_robot_fly():
    from tdacm.sim import build_world, load_scenario
    from tdacm.sim.robot import MIN_THRUST_TO_WEIGHT

    for name in ("paper-in-fov", "custom-robot-example"):
        s = build_world(load_scenario(name)).robot.system
        assert 4 * s.base.max_thrust >= MIN_THRUST_TO_WEIGHT * s.total_mass * 9.81


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    from tdacm.sim import run_scenario

    base = tmp_path_factory.mktemp("edges")
    cfg = base / "cfg.toml"
    cfg.write_text(FAST)
    run_scenario("paper-in-fov", out=base / "run", config=cfg, duration=0.2)
    return base / "run"


def _one_error(capsys, *words):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:"), err
    for w in words:
        assert w in err[0], err[0]


@pytest.mark.parametrize("command", ["plot", "replay"])
def test_a_truncated_timeseries_is_one_error_line(tmp_path, run_dir, capsys, command):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(run_dir, bad)
    data = (bad / "timeseries.npz").read_bytes()
    (bad / "timeseries.npz").write_bytes(data[: len(data) // 2])
    assert main([command, str(bad)]) == 2
    _one_error(capsys, "timeseries.npz", "cannot be read")
    (bad / "timeseries.npz").write_bytes(b"")
    assert main([command, str(bad)]) == 2
    _one_error(capsys, "timeseries.npz")


def test_out_under_a_file_is_one_error_line(tmp_path, run_dir, capsys):
    f = tmp_path / "afile"
    f.write_text("x")
    assert main(["plot", str(run_dir), "--out", str(f / "figs")]) == 2
    _one_error(capsys, "--out", "is a file, not a folder")
    assert main(["replay", str(run_dir), "--out", str(f / "r.gif")]) == 2
    _one_error(capsys, "--out", "is a file, not a folder")
    assert main(["run", "paper-in-fov", "--out", str(f / "run")]) == 2
    _one_error(capsys, "--out")
    assert main(["plot", str(run_dir), "--out", str(f)]) == 2
    _one_error(capsys, "--out", "is a file")


def test_gif_frame_delays_match_the_stated_speed(tmp_path):
    from tdacm.viz.replay import GIF_DELAY_QUANTUM, playback_plan, write_animation

    # a 2 s run logged at 50 Hz (the case that played in 1.7 s)
    stride, fps, speed = playback_plan(2.0, 101, quantum=GIF_DELAY_QUANTUM)
    delay = 1.0 / fps
    assert round(delay / GIF_DELAY_QUANTUM) * GIF_DELAY_QUANTUM == pytest.approx(delay)
    shown = len(range(0, 101, stride))
    frames = [np.full((8, 8, 3), i, np.uint8) for i in range(shown)]
    path = write_animation(frames, tmp_path / "a.gif", fps)
    with Image.open(path) as im:
        total = 0
        for i in range(im.n_frames):
            im.seek(i)
            total += im.info["duration"]
    simulated = shown * stride * 0.02
    assert total / 1000 == pytest.approx(simulated / speed, abs=1e-9)
    assert speed == pytest.approx(1.0, abs=1e-9)


def test_replay_title_states_the_speed_the_gif_plays(run_dir):
    from tdacm.viz.replay import playback_plan

    stride, fps, speed = playback_plan(10.0, 501, fps=30, max_frames=60, quantum=0.01)
    assert 1 / fps == pytest.approx(0.03)  # 30 fps is a whole 3 cs delay: kept
    stride, fps, speed = playback_plan(10.0, 501, fps=35, max_frames=60, quantum=0.01)
    assert 1 / fps == pytest.approx(0.03)  # 28.6 ms cannot be stored: 3 cs, the speed says so
    assert speed == pytest.approx(stride * 0.02 * fps)


def test_demo_and_make_demo_write_distinct_folders():
    make = (ROOT / "Makefile").read_text()
    target = re.search(r"^demo:.*\n\t(.*)$", make, re.M).group(1)
    make_out = re.search(r"--out (\S+)", target).group(1)
    demo_out = cli.build_parser().parse_args(["demo"]).out
    assert make_out != demo_out
    readme = (ROOT / "README.md").read_text()
    assert f"output in {make_out}/" in readme and f"writes {demo_out}/" in readme


def test_bench_writes_only_tables_on_stdout(tmp_path, monkeypatch, capsys):
    import tdacm.bench as bench
    from tdacm.bench import model

    def stub(out, repeats):  # the bench's own loggers, without its minutes of timing
        model.report.info("system  n  terms")
        model.log.info(f"written {tmp_path / 'bench.json'}")

    monkeypatch.setattr(bench, "run_model_bench", stub)
    monkeypatch.setattr(cli, "numba_cache_is_cold", lambda: False)
    assert main(["bench", "--out", str(tmp_path)]) == 0
    cap = capsys.readouterr()
    assert cap.out == "system  n  terms\n"
    assert "written" in cap.err


def test_an_error_after_ctrl_c_during_a_compilation_exits_130(monkeypatch, capsys):
    """Numba left half-built by Ctrl-C raises RuntimeError on the next call, and its objects
    complain when collected: one line and status 130, no traceback."""

    def interrupted(args):
        cli._on_sigint(2, None)  # what Ctrl-C does

    def then_numba_fails(args):
        try:
            interrupted(args)
        except KeyboardInterrupt:
            pass  # caught by the loop (a run interrupted: its data written) ...
        raise RuntimeError("no compiled object yet for <Library '_matvec'>")  # ... then this

    for func in (interrupted, then_numba_fails):
        monkeypatch.setattr(cli, "_cmd_info", func)
        assert main(["info"]) == 130
        err = capsys.readouterr().err.strip().splitlines()
        assert err == ["interrupted (Ctrl-C)"]
    # the finalizer errors of numba/llvmlite objects after the interrupt are dropped
    seen = []
    hook = cli._unraisable_hook(lambda u: seen.append(u))

    class OutputString:  # stands for llvmlite.binding.ffi.OutputString
        pass

    OutputString.__module__ = "llvmlite.binding.ffi"

    def _raw_object_cache_notify(data):  # llvmlite's ctypes callback, where Ctrl-C lands
        pass

    _raw_object_cache_notify.__module__ = "llvmlite.binding.executionengine"

    class Unraisable:
        object = OutputString()
        exc_type = AttributeError

    hook(Unraisable())
    Unraisable.object, Unraisable.exc_type = _raw_object_cache_notify, KeyboardInterrupt
    hook(Unraisable())
    Unraisable.object, Unraisable.exc_type = print, KeyboardInterrupt  # the interrupt itself
    hook(Unraisable())
    assert seen == []
    Unraisable.object, Unraisable.exc_type = object(), ValueError  # not ours: reported
    hook(Unraisable())
    assert len(seen) == 1
    cli._interrupted = False
    hook(Unraisable())  # before any interrupt, everything is reported
    Unraisable.object, Unraisable.exc_type = OutputString(), AttributeError
    hook(Unraisable())
    assert len(seen) == 3
    sys.unraisablehook = sys.__unraisablehook__


def test_rerun_under_a_file_is_one_error_line_before_the_run(tmp_path, capsys):
    f = tmp_path / "afile"
    f.write_text("x")
    out = tmp_path / "run"
    assert main(["run", "paper-in-fov", "--rerun", str(f / "x.rrd"), "--out", str(out)]) == 2
    _one_error(capsys, "--rerun", "is a file, not a folder")
    assert not out.exists()  # nothing run


SPEC = 'scenario = "paper-in-fov"\nruns = 2\nseed = 7\nduration = 0.06\n'


@pytest.mark.parametrize("address", ["not-an-address", "tcp://127.0.0.1:1"])
def test_a_bad_or_unreachable_scheduler_is_one_error_line(tmp_path, capsys, address):
    pytest.importorskip("distributed")
    import time

    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    t0 = time.perf_counter()
    code = main(["-q", "campaign", str(spec), "--scheduler", address,
                 "--out", str(tmp_path / "c")])  # fmt: skip
    assert code == 2
    _one_error(capsys, "--scheduler", address)
    assert time.perf_counter() - t0 < 20  # not the 30 s default connect timeout


def test_identify_on_a_truncated_timeseries_is_one_error_line(tmp_path, run_dir, capsys):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(run_dir, bad)
    data = (bad / "timeseries.npz").read_bytes()
    (bad / "timeseries.npz").write_bytes(data[: len(data) // 2])
    assert main(["-q", "identify", str(bad), "--params", "E", "--out", str(tmp_path / "id")]) == 2
    _one_error(capsys, "timeseries.npz", "cannot be read")


def test_extends_in_a_config_file_is_one_error_line(tmp_path, capsys):
    cfg = tmp_path / "cfg.toml"
    cfg.write_text('extends = "ground-test-a"\n')
    out = tmp_path / "run"
    assert main(["run", "paper-in-fov", "--config", str(cfg), "--out", str(out)]) == 2
    _one_error(capsys, "extends", str(cfg), "paper-in-fov")
    assert not out.exists()


@pytest.mark.filterwarnings("ignore:No artists with labels")  # no tensions to draw
def test_the_actuation_figure_draws_a_malformed_u(tmp_path, run_dir):
    import shutil

    from tdacm.viz import plot_run_dir

    bad = tmp_path / "bad"
    shutil.copytree(run_dir, bad)
    with np.load(bad / "timeseries.npz") as d:
        arrays = {k: d[k] for k in d.files}
    arrays["u"] = arrays["u"][:, :3]  # three entries where a flying TD-ACM has eight
    np.savez(bad / "timeseries.npz", **arrays)
    assert plot_run_dir(bad, formats=("png",), kinds=("actuation",))


def test_a_rod_too_heavy_to_fly_is_named_as_the_cause(tmp_path, capsys):
    cfg = tmp_path / "thick.toml"
    cfg.write_text("[robot.rod]\ndiameter = 0.5\n")
    assert main(["-q", "run", "paper-in-fov", "--config", str(cfg),
                 "--out", str(tmp_path / "o")]) == 2  # fmt: skip
    _one_error(capsys, "the rod is the heaviest part", "robot.rod.diameter = 0.5 m")


def test_a_topic_map_without_its_topics_table_is_named(tmp_path, capsys):
    from tdacm.recording import RecordingError, load_topic_map

    tmap = tmp_path / "lab.toml"
    tmap.write_text('[topic]\n"/vicon/drone/pose" = "drone_pose"\n')
    with pytest.raises(RecordingError, match=r"has no \[topics\] table \(\[topic\] is not"):
        load_topic_map(tmap)
    tmap.write_text('"/vicon/drone/pose" = "drone_pose"\n"/arm" = { position = "strains" }\n')
    assert load_topic_map(tmap) == {"/vicon/drone/pose": "drone_pose",
                                    "/arm": {"position": "strains"}}  # fmt: skip


def test_ctrl_c_while_the_figures_are_written_says_interrupted(tmp_path, capsys, monkeypatch):
    import tdacm.viz

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(tdacm.viz, "plot_run_dir", interrupted)
    code, out = _run(tmp_path, "cut", "", duration="0.1")
    cap = capsys.readouterr()
    assert code == 130 and cap.out == ""
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] and (out / "timeseries.npz").is_file()

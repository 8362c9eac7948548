"""The command-line entry points: clean stdout, exit codes, and rejected inputs (exit 2 with a
message naming the flag or key)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tdacm.cli import main

ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}


def test_help_lists_commands():
    out = subprocess.run(
        [sys.executable, "-m", "tdacm.cli", "--help"], capture_output=True, text=True, check=True
    )
    for cmd in (
        "info",
        "demo",
        "bench",
        "run",
        "plot",
        "replay",
        "campaign",
        "export",
        "import",
        "replay-recording",
        "identify",
    ):
        assert cmd in out.stdout


def test_version(capsys):
    import tdacm

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"tdacm {tdacm.__version__}"


def test_info_prints_model_summary(capsys):
    assert main(["info"]) == 0
    text = capsys.readouterr().out
    assert "n = 8 generalized coordinates" in text
    assert "0.7331" in text and "Gauss-Legendre" in text and "EI = 0.03927" in text
    # the default sensors and what they allow (tdacm.estimation.hover_estimate_limits)
    assert "velocity 4.58 mm/s" in text and "tilt 0.65 mrad" in text


def test_demo_writes_plot_data_and_bends_toward_static_value(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--duration", "4"]) == 0
    for name in (
        "hover_tendon_step.png",
        "hover_tendon_step.npz",
        "hover_tendon_step.csv",
        "summary.json",
    ):
        assert (tmp_path / name).stat().st_size > 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["completed"]
    # the tendon step bends the rod about z; it oscillates about the static curvature with the
    # drone held (0.113 1/m: the rod's weight and the camera pull it back from 0.255)
    kz, static = summary["final_q_s"][1], summary["static_q_s_drone_held"][1]
    assert static == pytest.approx(0.1130, abs=5e-4)
    assert 0.7 * static < kz < 1.3 * static
    cap = capsys.readouterr()
    json.loads(cap.out)  # stdout: the summary only
    assert "Demo output written to" in cap.err


# ------------------------------------------------------------------ rejected inputs (exit 2)
def _rejected(capsys, argv, *needles):
    """``main(argv)`` exits 2 (argparse or our checks) and stderr names every needle."""
    try:
        code = main(argv)
    except SystemExit as e:  # argparse
        code = e.code
    err = capsys.readouterr().err
    assert code == 2, (argv, err)
    for n in needles:
        assert n in err, (argv, n, err)
    assert "Traceback" not in err
    return err


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "-1", "0"])
def test_duration_flag_rejected(capsys, tmp_path, value):
    _rejected(capsys, ["run", "paper-in-fov", "--out", str(tmp_path), f"--duration={value}"],
              "--duration")  # fmt: skip


def test_duration_shorter_than_dt_rejected(capsys, tmp_path):
    _rejected(capsys, ["run", "paper-in-fov", "--out", str(tmp_path), "--duration", "0.01"],
              "--duration", "dt")  # fmt: skip


def test_seed_flag_rejected(capsys, tmp_path):
    _rejected(capsys, ["run", "paper-in-fov", "--out", str(tmp_path), "--seed", "-1"], "--seed")


def _cfg(tmp_path, text, name="cfg.toml"):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("seed = -1\n", "seed"),
        ("[controller]\npretension = -5.0\n", "controller.pretension"),
        ("[controller]\nmax_tilt = -0.1\n", "controller.max_tilt"),
        ("[ibvs]\nmax_joint_rate = 0.0\n", "ibvs.max_joint_rate"),
        ("[ibvs]\nmax_joint_rate = -1.0\n", "ibvs.max_joint_rate"),
        ("[recovery]\nconfirm = 0\n", "recovery.confirm"),
        ("[recovery]\nlose = 0\n", "recovery.lose"),
        ("dt = 0.5\nduration = 0.2\n", "dt"),
        ("dt = 0.1\n", "dt = 0.1"),
        ("dt = 0.04\nsubsteps = 1\n", "dt / substeps"),
        ("[desired]\nq = [0.0, 0.0, 0.0, 0.0, 0.0, 0.6, 0.0, 0.0]\n", "desired.q"),
    ],
)
def test_scenario_values_rejected(capsys, tmp_path, text, key):
    cfg = _cfg(tmp_path, text)
    _rejected(capsys, ["run", "paper-in-fov", "--out", str(tmp_path / "o"), "--config", cfg], key)


def test_seed_in_scenario_file_rejected(capsys, tmp_path):
    from tdacm.sim.scenario import _package_files

    text = (_package_files() / "ground-test-a.toml").read_text().replace("seed = 0", "seed = -1")
    p = _cfg(tmp_path, text, "sc.toml")
    _rejected(capsys, ["run", p, "--out", str(tmp_path / "o")], "seed", "sc.toml")


def test_non_utf8_files_rejected(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b'name = "caf\xe9"\n')
    _rejected(capsys, ["run", str(bad), "--out", str(tmp_path / "o")], "bad.toml", "UTF-8")
    _rejected(capsys, ["run", "paper-in-fov", "--config", str(bad), "--out", str(tmp_path / "o")],
              "bad.toml", "UTF-8")  # fmt: skip
    _rejected(capsys, ["campaign", str(bad), "--out", str(tmp_path / "c")], "bad.toml", "UTF-8")


def test_directories_rejected(capsys, tmp_path):
    _rejected(capsys, ["run", str(tmp_path), "--out", str(tmp_path / "o")], "is a directory")
    _rejected(capsys, ["run", "paper-in-fov", "--config", str(tmp_path), "--out", str(tmp_path / "o")],
              "--config", "is a directory")  # fmt: skip


def test_campaign_scenario_unknown_and_relative_path(capsys, tmp_path, monkeypatch):
    from tdacm.campaign import load_spec
    from tdacm.sim.scenario import _package_files

    spec = _cfg(tmp_path, 'scenario = "no-such-scenario"\nruns = 1\n', "spec.toml")
    _rejected(capsys, ["campaign", spec, "--out", str(tmp_path / "c")], "scenario", "no-such")
    # a relative path is resolved against the spec's folder, not the current directory
    sub = tmp_path / "specs"
    sub.mkdir()
    (sub / "mine.toml").write_text((_package_files() / "ground-test-a.toml").read_text())
    (sub / "spec.toml").write_text('scenario = "mine.toml"\nruns = 1\n')
    monkeypatch.chdir(tmp_path)
    assert Path(load_spec(sub / "spec.toml").scenario) == (sub / "mine.toml").resolve()
    (sub / "spec2.toml").write_text('scenario = "missing.toml"\nruns = 1\n')
    _rejected(capsys, ["campaign", str(sub / "spec2.toml")], "missing.toml", "does not exist")


@pytest.mark.parametrize("value", ["0", "-1"])
def test_workers_rejected(capsys, tmp_path, value):
    _rejected(capsys, ["campaign", "x.toml", "--workers", value], "--workers")


def test_replay_and_plot_of_missing_folder(capsys, tmp_path):
    _rejected(capsys, ["replay", str(tmp_path / "missing")], "RUN_DIR", "missing")
    _rejected(capsys, ["replay", str(tmp_path / "missing"), "--rerun"], "RUN_DIR")
    _rejected(capsys, ["plot", str(tmp_path / "missing")], "RUN_DIR")
    _rejected(capsys, ["replay", str(tmp_path)], "timeseries.npz")


@pytest.mark.parametrize("flag", ["--fps", "--max-frames", "--speed"])
def test_replay_zero_flags(capsys, tmp_path, flag):
    _rejected(capsys, ["replay", str(tmp_path), flag, "0"], flag)


def test_bench_progress_line_on_stderr(monkeypatch, capsys, tmp_path):
    import tdacm.bench.loop as loop_bench
    import tdacm.bench.model as bench

    monkeypatch.setattr(bench, "bench_system", lambda name, s, repeats, duration=5.0: {
        "system": name, "n": s.n, "terms_us": 1.0, "forward_dynamics_api_us": 1.0,
        "forward_dynamics_kernel_us": 1.0, "rk4_dt_s": 0.01, "real_time_factor": 1.0})  # fmt: skip
    monkeypatch.setattr(bench, "bench_stiff", lambda name, s, method, **kw: {
        "system": name, "method": method, "n": s.n, "w_max_rad_s": 1.0, "real_time_factor": 1.0,
        "tip_error_max_m": 0.0, "check_s": 0.5, "reference": "x", "tip_travel_m": 0.0,
        "completed": True, "_ref": None})  # fmt: skip
    monkeypatch.setattr(bench, "paper_system", lambda **kw: type("S", (), {"n": 8})())
    one = {"wall_per_sim_second": 0.1, "real_time_factor": 10.0}
    monkeypatch.setattr(loop_bench, "time_loop", lambda ov, repeats=5: one)
    share = {"period_ms": 2.0, "compiled_ms": 0.5, "compiled_fraction": 0.25,
             "cap_real_time_factor": 40.0, "top": {}}  # fmt: skip
    monkeypatch.setattr(loop_bench, "compiled_share", lambda ov: share)
    assert main(["bench", "--out", str(tmp_path)]) == 0
    cap = capsys.readouterr()
    assert "bench: model 1/2" in cap.err and "bench: model 2/2" in cap.err
    assert "bench: stiff integrators" in cap.err and "closed loop" in cap.err
    assert "bench:" not in cap.out and "RTF" in cap.out
    assert "without any Python at most 40.0x" in cap.err and "40.0x" in cap.out


# ------------------------------------------------------------------ subprocess behaviour
def _run_cli(args, cwd, **kw):
    return subprocess.run([sys.executable, "-m", "tdacm.cli", *args], capture_output=True,
                          text=True, cwd=cwd, env=ENV, **kw)  # fmt: skip


def test_run_stdout_is_the_summary_json_only(tmp_path):
    cfg = _cfg(tmp_path, '[cameras]\nglobal_every = 0\nglobal_backend = "auto"\n')
    r = _run_cli(["run", "paper-in-fov", "--duration", "0.06", "--out", "o", "--config", cfg,
                  "--rerun", "o/run.rrd"], tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)  # no PyBullet banner, no "written to" line
    assert summary["scenario"] == "paper-in-fov" and summary["duration"] == pytest.approx(0.06)
    assert "Run written to" in r.stderr
    assert (tmp_path / "o" / "run.rrd").stat().st_size > 0  # --rerun: converted at the end


def _wait_for(proc, path_or_fn, timeout=120):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if path_or_fn():
            return True
        if proc.poll() is not None:
            return False
        time.sleep(0.2)
    return False


def test_ctrl_c_during_run_writes_partial_and_exits_130(tmp_path):
    cfg = _cfg(tmp_path, "[cameras]\nglobal_every = 0\n")
    proc = subprocess.Popen(
        # long enough to be still running when Ctrl-C arrives (a warm cache runs ~9x real time)
        [sys.executable, "-m", "tdacm.cli", "run", "paper-in-fov", "--duration", "600",
         "--out", "o", "--config", cfg],
        cwd=tmp_path, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        # SIGINT at its default in the child, as in a terminal (a shell's background job, e.g. a
        # CI runner, starts it ignored, and Python then never raises KeyboardInterrupt)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    # wait until the loop runs (scene.png is written before the first step), then Ctrl-C
    assert _wait_for(proc, lambda: (tmp_path / "o" / "scene.png").is_file())
    # the first period loads the blocks' compiled steps from numba's cache (about 2 s on a
    # loaded 2-core machine) before the first step is stored
    time.sleep(4.0)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert [ln for ln in err.splitlines() if ln.startswith("interrupted")] != []
    data = np.load(tmp_path / "o" / "timeseries.npz")
    assert 1 <= len(data["t"]) < 30000
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["interrupted"] and summary["termination_reason"].startswith("interrupted")
    assert out == ""

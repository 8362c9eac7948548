"""The second compiling process of a cold first run (tdacm.loop.precompile)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tdacm.loop import precompile
from tdacm.sim import load_scenario


class FakeChild:
    """Stands in for the subprocess: records what the module does with it."""

    started: list = []

    def __init__(self, args, **kwargs):
        self.args = args
        self.killed = self.waited = False
        FakeChild.started.append(self)

    def wait(self, timeout=None):
        self.waited = True
        return 0

    def poll(self):
        return None  # still compiling

    def kill(self):
        self.killed = True


@pytest.fixture
def fake_child(monkeypatch):
    FakeChild.started = []
    monkeypatch.setattr(precompile.subprocess, "Popen", FakeChild)
    monkeypatch.setattr(precompile, "_child", None)
    monkeypatch.delenv("NUMBA_DISABLE_JIT", raising=False)
    return FakeChild


def test_started_only_on_a_cold_cache_and_two_cores(monkeypatch, fake_child):
    monkeypatch.setattr(precompile.os, "cpu_count", lambda: 2)
    monkeypatch.setattr(precompile, "numba_cache_is_cold", lambda: False)
    assert not precompile.start()
    monkeypatch.setattr(precompile, "numba_cache_is_cold", lambda: True)
    monkeypatch.setattr(precompile.os, "cpu_count", lambda: 1)
    assert not precompile.start()  # one core: both halves would share it
    monkeypatch.setattr(precompile.os, "cpu_count", lambda: 2)
    monkeypatch.setenv("TDACM_PARALLEL_COMPILE", "0")
    assert not precompile.start()  # the user's opt-out
    monkeypatch.delenv("TDACM_PARALLEL_COMPILE")
    assert precompile.start()
    assert not precompile.start()  # at most one per process
    assert len(fake_child.started) == 1
    assert fake_child.started[0].args[1:] == ["-m", "tdacm.loop.precompile"]
    precompile.wait()
    assert fake_child.started[0].waited and precompile._child is None
    precompile.wait()  # no child: a no-op


def test_with_the_scenario_the_child_builds_its_loop_and_the_main_waits_for_rk4_only(
    monkeypatch, fake_child
):
    import pickle

    monkeypatch.setattr(precompile.os, "cpu_count", lambda: 2)
    monkeypatch.setattr(precompile, "numba_cache_is_cold", lambda: True)
    sc = load_scenario("paper-in-fov")
    assert precompile.start(sc)
    args = fake_child.started[0].args
    assert args[1:3] == ["-m", precompile.AHEAD_MODULE]
    with open(args[3], "rb") as f:  # the run's scenario, handed over
        assert pickle.load(f).config == sc.config
    precompile.os.unlink(args[3])
    # the warm-up waits until the integrator is cached, not for the child's end
    answers = iter([True, True, False])  # uncached twice, then cached
    monkeypatch.setattr(precompile, "_uncached", lambda kernels: next(answers))
    monkeypatch.setattr(precompile, "POLL", 0.0)
    precompile.wait(("rk4_run",))
    child = fake_child.started[0]
    assert not child.waited and not child.killed and precompile._child is child
    precompile.stop()  # the run's end stops it, whatever it still compiles
    assert child.killed and precompile._child is None


def test_compile_ahead_uses_the_loops_signatures():
    """The second process must compile the signatures the loop calls, or its cache entries
    would go unused: the integrator and the backbone poses (:func:`compile_second_half`, its
    first part) and, knowing the scenario, the servo's command step and the plant's and the
    controller's steps. After a short run, it adds no signature."""
    from tdacm.control import hierarchical
    from tdacm.loop import plant, servo
    from tdacm.sim import build_loop
    from tdacm.sim.compile_ahead import compile_ahead
    from tdacm.system import kernels as K

    sc = load_scenario("paper-in-fov").with_overrides(
        {"cameras": {"local_renderer": "analytic", "global_every": 0}}
    )
    loop = build_loop(sc, 0).loop
    loop.run(0.1)
    loop.plant.system.backbone(loop.plant.state.q)  # the scene picture's call
    loop.close()
    kernels = (K.rk4_run, K.chain_poses, plant.plant_step, hierarchical.controller_step,
               servo.servo_command)  # fmt: skip
    before = {k.py_func.__name__: list(k.signatures) for k in kernels}
    assert all(before.values()), before
    compile_ahead(sc)
    after = {k.py_func.__name__: list(k.signatures) for k in kernels}
    assert after == before


def test_stop_kills_the_child(monkeypatch, fake_child):
    monkeypatch.setattr(precompile.os, "cpu_count", lambda: 2)
    monkeypatch.setattr(precompile, "numba_cache_is_cold", lambda: True)
    assert precompile.start()
    precompile.stop()
    assert fake_child.started[0].killed and precompile._child is None


def test_cli_run_kills_the_child_when_the_scenario_is_rejected(
    monkeypatch, fake_child, tmp_path, capsys
):
    from tdacm import _compiling, cli

    monkeypatch.setattr(precompile.os, "cpu_count", lambda: 2)
    monkeypatch.setattr(precompile, "numba_cache_is_cold", lambda: True)
    monkeypatch.setattr(cli, "numba_cache_is_cold", lambda: True)
    notes = []  # what the compile notice adds at the first compile
    monkeypatch.setattr(_compiling, "add_note", notes.append)
    bad = tmp_path / "bad.toml"
    # passes the schema checks, fails the one that builds the robot (RK4 step too long)
    bad.write_text("dt = 0.04\nsubsteps = 1\n")
    code = cli.main(["run", "paper-in-fov", "--config", str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "RK4 step limit" in err
    assert fake_child.started and fake_child.started[0].killed
    assert notes == ["in two processes"]


def test_entry_point_runs_on_a_warm_cache():
    # the suite's kernels are cached by now: the entry point loads them and exits 0
    proc = subprocess.run(
        [sys.executable, "-m", "tdacm.loop.precompile"], capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_cold_cache_detection_asks_numbas_index(monkeypatch, tmp_path):
    # the suite's process has the kernels cached (loaded or compiled): warm
    assert not precompile.numba_cache_is_cold()
    assert not precompile._index_files_missing()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))  # the fallback reads it per call
    assert precompile._index_files_missing()
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    # an empty cache folder, in a fresh process (numba fixes the folder at import)
    code = "from tdacm.loop.precompile import numba_cache_is_cold as c; print(c())"
    env = dict(__import__("os").environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.stdout.strip().splitlines()[-1] == "True", out.stderr[-2000:]


def test_cold_start_ab_alternates_and_reports_the_ratio(monkeypatch):
    import tdacm.bench.loop as lb

    calls = []

    def fake(parallel, warm=False):
        calls.append(parallel)
        proc = subprocess.CompletedProcess([], 0, "", "")
        return (40.0 if parallel else 60.0) + len(calls), proc, None

    monkeypatch.setattr(lb, "_cold_run", fake)
    res = lb.cold_start_ab(2, progress=lambda *a: None)
    assert calls == [False, True, False, True]
    assert res["one_process_s"] == [61.0, 63.0] and res["two_processes_s"] == [42.0, 44.0]
    assert res["ratio_of_medians"] == pytest.approx(62.0 / 43.0)

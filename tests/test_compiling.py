"""What compiles says so (tdacm._compiling): a first compile prints one line on stderr, then a
progress bar over the kernels; a cached kernel prints nothing; ``-q`` silences both."""

from __future__ import annotations

import logging
import os
import subprocess
import sys

import pytest

from tdacm import _compiling

_SRC = os.path.dirname(os.path.dirname(os.path.abspath(_compiling.__file__)))


def _run(code: str, cache) -> subprocess.CompletedProcess:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), TDACM_KERNEL_CACHE="local")
    env["PYTHONPATH"] = os.pathsep.join([_SRC, *filter(None, [env.get("PYTHONPATH")])])
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)


#: one small kernel of the package, compiled inside the engine's scope
_FIRST_USE = (
    "import numpy as np\n"
    "from tdacm._compiling import compiling\n"
    "from tdacm.lie.se3 import _exp_coefficients as kernel\n"
    "with compiling('engine'):\n"
    "    kernel(0.5)\n"
    "print(sum(kernel.stats.cache_misses.values()))\n"
)


def test_a_first_compile_prints_the_line_then_a_bar_and_a_cached_one_nothing(tmp_path):
    first = _run(_FIRST_USE, tmp_path)
    assert first.returncode == 0, first.stderr
    assert first.stdout.strip() == "1"  # it did compile
    lines = first.stderr.splitlines()
    assert lines[0].startswith("tdacm: compiling the engine's kernels (once")
    assert lines[0].endswith(" ...")
    assert "compiling:" in first.stderr and "kernel" in first.stderr  # the bar (tqdm)
    again = _run(_FIRST_USE, tmp_path)  # the same cache: loaded, not compiled
    assert again.returncode == 0, again.stderr
    assert again.stdout.strip() == "0"
    assert "compiling" not in again.stderr


def _fake_compile(dispatcher) -> None:
    """numba's compile event of ``dispatcher`` without compiling anything."""
    from numba.core import event

    with event.trigger_event("numba:compile", data={"dispatcher": dispatcher, "args": ()}):
        pass


@pytest.fixture
def logger_state():
    """Restore the ``tdacm`` logger and the notice's state after the test."""
    logger = logging.getLogger("tdacm")
    saved = (logger.level, list(logger.handlers), dict(_compiling._state))
    _compiling._state.update(job=None, bar=None, announced=set(), notes=[])
    yield
    logger.setLevel(saved[0])
    logger.handlers[:] = saved[1]
    _compiling._state.clear()
    _compiling._state.update(saved[2])


def test_quiet_silences_the_notice(logger_state, capsys):
    from tdacm._log import configure_logging
    from tdacm.lie.se3 import _exp_coefficients as kernel

    configure_logging(quiet=True)  # what tdacm -q does
    with _compiling.compiling("engine"):
        _fake_compile(kernel)
    assert capsys.readouterr().err == ""


def test_one_line_per_job_and_a_bar_per_scope(logger_state, capsys, monkeypatch):
    from tdacm._log import configure_logging
    from tdacm.lie.se3 import _exp_coefficients as kernel

    configure_logging()
    monkeypatch.setattr(_compiling, "_estimates_cache", {})
    with _compiling.compiling("identify"):
        _fake_compile(kernel)
        _fake_compile(kernel)
    err = capsys.readouterr().err
    assert err.startswith("tdacm: compiling identification's kernels (once; cached afterwards)")
    assert "compiling: " in err and "2kernel" in err.replace(" ", "")
    with _compiling.compiling("identify"):  # the same job again: its bar, not its line
        _fake_compile(kernel)
    err = capsys.readouterr().err
    assert "tdacm: compiling" not in err and "compiling: " in err
    _fake_compile(kernel)  # outside a job: a line naming none, once
    _fake_compile(kernel)
    err = capsys.readouterr().err
    assert err.count("tdacm: compiling numba kernels (once; cached afterwards) ...") == 1
    _compiling._close_bar()


def test_the_estimate_counts_what_the_cache_lacks(monkeypatch):
    from tdacm.lie.se3 import _exp_coefficients as kernel

    kernel(0.5)  # loaded or compiled: in this process now
    (types,) = [str(k) for k in kernel.overloads]
    monkeypatch.setattr(_compiling, "_estimates_cache", {
        "engine": {"seconds": 100.0, "kernels": [
            ["tdacm.lie.se3", "_exp_coefficients", types, 30.0],  # held: not counted
            ["tdacm.lie.se3", "_exp_coefficients", "(float32,)", 25.0],  # other types: to compile
            ["tdacm.not_imported", "f", "()", 45.0],  # its module not imported: to compile
        ]},
    })  # fmt: skip
    assert _compiling.remaining("engine") == (2, 70.0)
    line, total = _compiling.notice_line("engine")
    assert total == 2
    assert line == (
        "tdacm: compiling the engine's kernels (once; 2 kernels, about 70 s; cached afterwards) ..."
    )
    assert _compiling.remaining("identify") is None
    line, total = _compiling.notice_line(None)
    assert line == "tdacm: compiling numba kernels (once; cached afterwards) ..." and total is None


def test_the_scope_decorator_keeps_the_outermost_job():
    seen = []

    @_compiling.compiling("identify")
    def inner():
        seen.append(_compiling._state["job"])

    with _compiling.compiling("engine"):
        inner()
    inner()
    assert seen == ["engine", "identify"] and _compiling._state["job"] is None


def test_the_jobs_of_the_notice_are_those_the_bench_measures():
    from tdacm.bench.compile import JOBS

    assert list(JOBS) == list(_compiling.JOBS)


def _job_of(fn) -> str | None:
    """The job of the :class:`~tdacm._compiling.compiling` scope ``fn`` is wrapped in."""
    cells = dict(zip(fn.__code__.co_freevars, fn.__closure__ or (), strict=True))
    return cells["job"].cell_contents if "job" in cells and "fn" in cells else None


def test_the_entry_points_of_the_jobs_open_their_scope():
    from tdacm.batch import Batch
    from tdacm.envs.vector import TipServoVectorEnv
    from tdacm.identify import identify
    from tdacm.sim import Simulation
    from tdacm.sim.batch import build_batch

    jobs = {
        "run": (Simulation.build, Simulation.run),
        "engine": (build_batch, Batch.reset, Batch.step, Batch.run),
        "vector-env": (TipServoVectorEnv.__init__, TipServoVectorEnv.reset, TipServoVectorEnv.step),
        "identify": (identify,),
    }
    assert {job: [_job_of(f) for f in fns] for job, fns in jobs.items()} == {
        job: [job] * len(fns) for job, fns in jobs.items()
    }
    assert set(jobs) == set(_compiling.JOBS)


def test_an_entry_is_saved_once_its_data_is_written(tmp_path):
    """numba writes a new entry's index before its data: another process polling the cache
    must not take the index alone for the compiled kernel."""
    from types import SimpleNamespace

    from tdacm._compiling import saved

    sig, magic = ("float64",), ("cpu", "features")
    index = {(sig, magic, "stamp"): "kernel-1.nbc", (("int64",), magic, "stamp"): "kernel-2.nbc"}
    cache_file = SimpleNamespace(
        _load_index=lambda: index, _data_path=lambda name: str(tmp_path / name)
    )
    disp = SimpleNamespace(
        overloads={},
        _cache=SimpleNamespace(_cache_file=cache_file),
        targetctx=SimpleNamespace(codegen=lambda: SimpleNamespace(magic_tuple=lambda: magic)),
    )
    assert not saved(disp, sig)  # in the index, its data not written yet
    (tmp_path / "kernel-1.nbc").write_bytes(b"data")
    assert saved(disp, sig)
    assert not saved(disp, ("bool",))  # not in the index
    disp.overloads[("bool",)] = object()
    assert saved(disp, ("bool",))  # compiled in this process

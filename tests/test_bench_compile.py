"""Where compile time goes (tdacm.bench.compile, ``tdacm bench --compile``): each function numba
compiles is recorded once per argument types with its inclusive and exclusive seconds, the
table ranks them and totals them, the command prints it and stores the notice's estimates."""

from __future__ import annotations

import json

import numpy as np
from numba import njit
from numba.core import event

from tdacm.bench import compile as C


def _recorded(fn, *args) -> list[dict]:
    rec = C.Recorder()

    class _Listener(event.Listener):
        def on_start(self, ev):
            rec.on_start(ev)

        def on_end(self, ev):
            rec.on_end(ev)

    with event.install_listener("numba:compile", _Listener()):
        fn(*args)
    return rec.records


def test_the_recorder_counts_each_compile_once_with_its_callees_apart():
    @njit
    def callee(x):
        return np.sin(x) * 2.0

    @njit
    def caller(x):
        return callee(x) + 1.0

    recs = _recorded(caller, 0.5)
    names = [r["qualname"].rsplit(".", 1)[-1] for r in recs]
    assert names == ["callee", "caller"]  # the callee ends first, inside its caller
    by = dict(zip(names, recs, strict=True))
    assert by["callee"]["depth"] == 1 and by["caller"]["depth"] == 0
    assert by["caller"]["types"] == "(float64,)"
    assert not any(r["failed"] for r in recs)
    # the caller's exclusive seconds leave out the callee's compile
    assert by["caller"]["inclusive_s"] >= by["callee"]["inclusive_s"] > 0
    assert (
        abs(
            by["caller"]["exclusive_s"]
            - (by["caller"]["inclusive_s"] - by["callee"]["inclusive_s"])
        )
        < 1e-9
    )
    assert _recorded(caller, 0.25) == []  # compiled already: nothing more
    assert len(_recorded(caller, 1)) == 2  # another argument type: both again


def _result(records) -> dict:
    return {"job": "run", "what": "a job", "wall_s": 10.0, "cpu_s": 9.0, "records": records}


def _rec(qualname, types, cpu, nrt=True, module="tdacm.x"):
    return {"module": module, "qualname": qualname, "types": types, "nrt": nrt,
            "exclusive_cpu_s": cpu, "exclusive_s": cpu + 0.5, "failed": False}  # fmt: skip


def test_the_table_ranks_functions_and_names_the_waste():
    res = _result([
        _rec("a", "(float64,)", 3.0), _rec("a", "(int64,)", 1.0),  # two argument types
        _rec("b", "(float64,)", 5.0, nrt=True), _rec("b", "(float64,)", 2.0, nrt=False),
        _rec("c", "()", 0.5),
    ])  # fmt: skip
    s = C.summary(res)
    assert (s["kernels"], s["functions"]) == (5, 3)
    assert s["compile_cpu_s"] == 11.5 and s["compile_s"] == 14.0
    assert s["several_types"] == ["tdacm.x.a"] and s["both_modes"] == ["tdacm.x.b"]
    text = C.table(res, top=2)
    rows = [ln for ln in text.splitlines() if ln.startswith("| `")]
    assert rows[0].startswith("| `tdacm.x.b` | 2 | 7.00 | 60.9% |")
    assert rows[1].startswith("| `tdacm.x.a` | 2 | 4.00 | 34.8% |")
    assert "| 1 others | 1 | 0.50 | 4.3% |" in text
    assert "| **total** | **5** | **11.5** |" in text
    assert "compiled in both runtime modes: tdacm.x.b" in text


def test_bench_compile_prints_the_table_and_stores_the_estimates(monkeypatch, tmp_path, capsys):
    from tdacm import cli

    res = _result([_rec("a", "(float64,)", 3.0), _rec("f", "()", 1.0, module="numpy.x")])
    monkeypatch.setattr(C, "profile", lambda job: {**res, "job": job})
    estimates = tmp_path / "compile_times.json"
    estimates.write_text(json.dumps({"jobs": {"identify": {"seconds": 9.0, "kernels": []}}}))
    monkeypatch.setattr("tdacm._compiling.ESTIMATES", estimates)
    out = tmp_path / "bench"
    code = cli.main(["bench", "--compile", "engine", "--write-estimates", "--out", str(out)])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "| **total** | **2** | **4.0** |" in cap.out
    assert json.loads((out / "compile.json").read_text())["engine"]["records"] == res["records"]
    stored = json.loads(estimates.read_text())["jobs"]
    assert stored["identify"]["seconds"] == 9.0  # a job measured before is kept
    # the package's kernels only, with their exclusive seconds
    assert stored["engine"] == {"seconds": 4.0, "kernels": [["tdacm.x", "a", "(float64,)", 3.0]]}


def test_bench_compile_rejects_an_unknown_job(capsys):
    from tdacm import cli

    try:
        code = cli.main(["bench", "--compile", "everything"])
    except SystemExit as exc:  # argparse
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and "--compile" in err and "everything" in err and "Traceback" not in err


def test_fill_compiles_the_blocks_before_the_engine_that_loads_them(monkeypatch, tmp_path):
    """``make test``'s warm-up: the run's and identification's jobs at once, then the engine
    with the vector env (which loads the blocks' steps the first phase cached); a failing
    process is reported and counted, the others still run."""
    started, waited = [], []

    class Proc:
        def __init__(self, cmd, **kwargs):
            self.jobs = tuple(cmd[cmd.index("run-jobs") + 1 : cmd.index("--work")])
            started.append((self.jobs, len(waited)))

        def wait(self, timeout=None):
            waited.append(self.jobs)
            return 3 if self.jobs == ("identify", "stiff") else 0

    monkeypatch.setattr(C.subprocess, "Popen", Proc)
    lines = []
    assert C.fill(progress=lines.append) == 1
    # both first-phase processes start before either is waited for; the engine's after both
    assert started == [
        (("run", "touch"), 0), (("identify", "stiff"), 0), (("engine", "vector-env"), 2)
    ]  # fmt: skip
    assert any("compiling identify, stiff failed" in line for line in lines)
    assert sorted(j for phase in C.PHASES for group in phase for j in group) == sorted(C.ALL_JOBS)

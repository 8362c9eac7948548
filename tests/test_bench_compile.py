"""benchmarks/bench_compile.py: numba's compile events recorded per function, nested compiles
counted once (exclusive seconds), the table ranked by them."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from numba import njit

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location(
        "bench_compile", ROOT / "benchmarks/bench_compile.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_nested_compiles_are_recorded_once_each(monkeypatch):
    bench = _bench()

    @njit
    def inner(x):
        return x * 3.0

    @njit
    def outer(x):
        return inner(x) + 1.0

    def job(name, work):
        assert outer(2.0) == 7.0  # compiles outer, and inner inside it

    monkeypatch.setattr(bench, "_job", job)
    res = bench.record("tiny", "unused")
    names = [r["function"].rsplit(".", 1)[-1] for r in res["records"]]
    assert "inner" in names and "outer" in names
    rec = {r["function"].rsplit(".", 1)[-1]: r for r in res["records"]}
    # the caller's exclusive time leaves out its callee's compile, which happened inside it
    assert (
        rec["outer"]["exclusive_s"]
        <= rec["outer"]["inclusive_s"] - rec["inner"]["inclusive_s"] + 1e-6
    )
    total = sum(r["exclusive_s"] for r in res["records"])
    assert total <= res["cpu_s"] + 1e-6  # every second counted once


def test_the_table_ranks_functions_by_their_own_compile_time():
    bench = _bench()
    res = {
        "job": "x",
        "wall_s": 10.0,
        "records": [
            {"function": "tdacm.a.small", "types": "()", "inclusive_s": 9.0, "exclusive_s": 1.0},
            {
                "function": "tdacm.a.big",
                "types": "(int64,)",
                "inclusive_s": 5.0,
                "exclusive_s": 5.0,
            },
            {
                "function": "tdacm.a.big",
                "types": "(float64,)",
                "inclusive_s": 3.0,
                "exclusive_s": 3.0,
            },
        ],
    }
    lines = bench.table(res, top=5).splitlines()
    assert lines[0].startswith("job x: 3 kernels (2 functions), 9 s of compile CPU")
    assert lines[4] == "| `a.big` | 2 | 8.0 |" and lines[5] == "| `a.small` | 1 | 1.0 |"

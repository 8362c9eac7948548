"""The engine's allocation count (``tdacm.bench.batch.allocations``): numba's runtime counts
every array a compiled step creates, in a fresh process with its statistics on."""

import math

from tdacm.bench.batch import _batch, allocations, period_split


def test_allocations_are_counted_over_every_world_period():
    """Two worlds for 0.2 s (11 periods each, the last one recorded without a plant step):
    the count covers the whole run (a child without the runtime's statistics fails). The
    figure itself is the speed benchmark's (docs/benchmarks.md), not bounded here."""
    res = allocations(2, 1, 0.2)
    assert res["world_periods"] == 2 * 11
    assert res["per_world_period"] == res["allocations"] / res["world_periods"]


def test_the_rate_benchmark_builds_the_scenario_it_names():
    """``bench_batch.py --rate-only --scenario ... --estimated`` measures the named scenario in
    the engine's configuration: two arms for `dual-in-fov`, the EKF per world with
    ``estimated``, and `paper-in-fov` on the true state by default (built, not timed)."""
    dual = _batch(2, 1, 0.1, scenario="dual-in-fov", estimated=True)
    assert dual.model.n_arms == 2 and dual.model.estimation.on
    paper = _batch(2, 1, 0.1)
    assert paper.model.n_arms == 1 and not paper.model.estimation.on


def test_the_period_split_times_both_halves_of_running_worlds():
    """``bench_batch.py --split-only``: the engine's act and sense halves of two worlds, timed
    apart over a few periods; both cost something and add up to the period (the figures are
    the benchmark page's, not bounded here)."""
    res = period_split(2, periods=4, skip=1)
    assert res["act_us"] > 0.0 and res["sense_us"] > 0.0
    assert math.isclose(res["period_us"], res["act_us"] + res["sense_us"])


def test_the_engines_cache_entries_are_its_own_modules(tmp_path, monkeypatch):
    """What the engine's compile benchmark removes: the entries of tdacm.batch.engine only,
    in numba's mirrored cache folder, an entry being written included."""
    from tdacm.bench.batch import engine_cache_entries

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    folder = tmp_path / "work" / "src" / "tdacm" / "batch"
    folder.mkdir(parents=True)
    names = ["engine.worlds-605.py311.nbi", "engine.worlds-605.py311.1.nbc",
             "engine.act-469.py311.1.nbc.tmp.0a1b", "random.draws-3.py311.nbi",
             "engine.py"]  # fmt: skip
    for name in names:
        (folder / name).write_text("")
    (tmp_path / "work" / "src" / "tdacm" / "loop").mkdir()
    (tmp_path / "work" / "src" / "tdacm" / "loop" / "engine.step-1.py311.nbi").write_text("")
    assert sorted(f.name for f in engine_cache_entries()) == sorted(names[:3])

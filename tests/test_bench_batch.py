"""The engine's allocation count (``tdacm.bench.batch.allocations``): numba's runtime counts
every array a compiled step creates, in a fresh process with its statistics on."""

from tdacm.bench.batch import allocations


def test_allocations_are_counted_over_every_world_period():
    """Two worlds for 0.2 s (11 periods each, the last one recorded without a plant step):
    the count covers the whole run (a child without the runtime's statistics fails). The
    figure itself is the speed benchmark's (docs/benchmarks.md), not bounded here."""
    res = allocations(2, 1, 0.2)
    assert res["world_periods"] == 2 * 11
    assert res["per_world_period"] == res["allocations"] / res["world_periods"]

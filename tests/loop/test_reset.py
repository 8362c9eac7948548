"""``ClosedLoop.reset()`` starts over from the plant's initial state at t = 0: ``run`` twice
gives the same run twice; ``reset(q0)`` starts elsewhere, at rest."""

import numpy as np

from tdacm.sim import build_loop, load_scenario

FAST = {"cameras": {"local_renderer": "analytic", "global_renderer": "planar", "global_every": 0}}


def test_run_twice_gives_the_same_run_twice():
    a = build_loop(load_scenario("paper-in-fov").with_overrides(FAST, "test"), seed=0)
    loop = a.loop
    try:
        first = loop.run(0.4)
        second = loop.run(0.4)
        assert not second.terminated, second.reason
        assert second.arrays["t"][0] == 0.0
        assert first.arrays.keys() == second.arrays.keys()
        for k, v in first.arrays.items():
            assert np.array_equal(v, second.arrays[k], equal_nan=True), k
        # a start elsewhere, then reset() without arguments: the initial state again
        q = a.world.q0.copy()
        q[5] += 0.1
        loop.reset(q)
        assert np.array_equal(loop.plant.state.q, q)
        assert not loop.plant.state.qd.any() and loop.plant.state.t == 0.0
        loop.step()
        loop.reset()
        assert np.array_equal(loop.plant.state.q, a.world.q0)
        assert np.array_equal(loop.plant.state.qd, a.world.qd0)
        assert loop.plant.state.t == 0.0
    finally:
        loop.close()

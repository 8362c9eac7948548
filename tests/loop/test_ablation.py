"""estimation.controller_truth: the low-level controller reads chosen coordinates from the plant."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tdacm.loop.ablation import TruthAblation, parse_controller_truth
from tdacm.loop.data import StateEstimate
from tdacm.sim import Simulation, build_world, load_scenario
from tdacm.sim.scenario import ScenarioError


def test_parse():
    assert parse_controller_truth("") == ([], [])
    assert parse_controller_truth("qd[3:5]") == ([], [3, 4])
    assert parse_controller_truth("q[0:2], qd[0:2],q[1]") == ([0, 1], [0, 1])
    assert parse_controller_truth("q[0:6],qd[0:6]", 8) == (list(range(6)), list(range(6)))
    for bad in ("qd[3:3]", "x[1]", "qd[1:]", "qd(3)", "q[-1]"):
        with pytest.raises(ValueError, match="estimation.controller_truth"):
            parse_controller_truth(bad)
    with pytest.raises(ValueError, match="past the robot's 8 coordinates"):
        parse_controller_truth("qd[6:9]", 8)


class Recorder:
    def __init__(self):
        self.seen = []

    def reset(self, estimate):
        self.seen.append(estimate)

    def step(self, estimate, command, dt):
        self.seen.append(estimate)
        return "u"


def test_block_replaces_exactly_the_named_coordinates():
    plant = SimpleNamespace(state=SimpleNamespace(q=np.arange(8.0) + 100, qd=np.arange(8.0) + 200))
    inner = Recorder()
    block = TruthAblation(inner, plant, [0, 1], [3, 4])
    est = StateEstimate(0.0, np.zeros(8), np.ones(8), np.eye(16))
    assert block.step(est, None, 0.02) == "u"
    seen = inner.seen[-1]
    assert seen.q.tolist() == [100, 101, 0, 0, 0, 0, 0, 0]
    assert seen.qd.tolist() == [1, 1, 1, 203, 204, 1, 1, 1]
    assert seen.P is est.P and seen.t == est.t
    assert est.q.tolist() == [0.0] * 8  # the estimate itself is not touched
    block.reset(est)
    assert inner.seen[-1].q[0] == 100


def test_scenario_key_is_validated():
    base = load_scenario("paper-in-fov")
    with pytest.raises(ScenarioError, match="estimation.controller_truth.*not q"):
        base.with_overrides({"estimation": {"source": "estimated", "controller_truth": "v[1]"}})
    with pytest.raises(ScenarioError, match="controller_truth needs estimation.source"):
        base.with_overrides({"estimation": {"controller_truth": "qd[3:5]"}})
    far = base.with_overrides(
        {"estimation": {"source": "estimated", "controller_truth": "qd[0:9]"}}
    )
    with pytest.raises(ScenarioError, match="past the robot's 8 coordinates"):
        build_world(far)


def test_short_run_with_the_controller_on_the_true_drone_velocity():
    sc = load_scenario("paper-in-fov").with_overrides(
        {
            "cameras": {"local_renderer": "analytic", "global_every": 0},
            "estimation": {"source": "estimated", "controller_truth": "qd[3:6]"},
        }
    )
    sim = Simulation(sc, duration=0.3, seed=0)
    seen = []
    loop = sim.build().loop
    inner = loop.controller.controller
    orig = inner.step

    def spy(estimate, command, dt):
        seen.append((estimate.qd.copy(), loop.plant.state.qd.copy()))
        return orig(estimate, command, dt)

    inner.step = spy
    result = loop.run(0.3)
    assert not result.terminated
    assert len(seen) >= 10
    for qd_seen, qd_true in seen:
        np.testing.assert_array_equal(qd_seen[3:6], qd_true[3:6])
    # the other coordinates are the estimator's, which differ from the plant's
    assert any(np.any(qd_seen[6:] != qd_true[6:]) for qd_seen, qd_true in seen)
    _, summary = Simulation(sc, duration=0.1, seed=0).run()
    assert summary["controller_truth"] == "qd[3:6]"

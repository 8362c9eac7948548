"""The engine's compile in two processes on a cold cache (tdacm.sim.compile_engine)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from tdacm.batch import engine as E
from tdacm.bench.batch import _batch
from tdacm.sim import compile_engine as CA


class FakeChild:
    """Stands in for the subprocess: records its arguments; ``ends_after`` polls it ends."""

    started: list = []
    ends_after = 2

    def __init__(self, args, **kwargs):
        self.args = args
        self.polls = 0
        self.killed = False
        FakeChild.started.append(self)

    def poll(self):
        self.polls += 1
        return 0 if self.polls > FakeChild.ends_after else None

    def kill(self):
        self.killed = True

    def wait(self, timeout=None):
        return 0


class FakeDispatcher:
    """A dispatcher that records the signatures compiled and has none cached."""

    def __init__(self):
        self.overloads = {}
        self.compiled = []

    def compile(self, sig):
        self.compiled.append(tuple(sig))


@pytest.fixture
def batch():
    return _batch(2, 1, 0.1)


@pytest.fixture
def fake(monkeypatch):
    FakeChild.started = []
    FakeChild.ends_after = 2
    monkeypatch.setattr(CA.subprocess, "Popen", FakeChild)
    monkeypatch.setattr(CA, "_child", None)
    monkeypatch.setattr(CA, "POLL", 0.0)
    monkeypatch.delenv("NUMBA_DISABLE_JIT", raising=False)
    monkeypatch.delenv("TDACM_PARALLEL_COMPILE", raising=False)
    monkeypatch.setattr(CA.os, "cpu_count", lambda: 2)
    return FakeChild


def test_the_types_compiled_ahead_are_those_of_the_engines_calls(batch):
    """Each signature is one the engine compiled for its own calls (this process's or numba's
    cache): a wrong type would compile a kernel no run loads."""
    batch.run()
    sig = CA.signatures(batch.model, batch.data)
    for name in ("reset_worlds", "sense", "act", "worlds"):
        assert CA.saved(getattr(E, name), sig[name]), name
    # the engine's Python callers call worlds with these types
    assert tuple(sig["worlds"]) in [tuple(s) for s in E.worlds.signatures]
    # every scenario's batch has the same types: one compile serves all
    other = _batch(3, 1, 0.1, scenario="dual-in-fov")
    assert CA.signatures(other.model, other.data) == sig


def test_started_only_when_the_entry_is_not_compiled_and_there_are_two_cores(
    monkeypatch, fake, batch
):
    model, data = batch.model, batch.data
    assert not CA.start(model, data)  # the engine is compiled already
    monkeypatch.setattr(CA, "saved", lambda dispatcher, sig: False)
    monkeypatch.setattr(CA.os, "cpu_count", lambda: 1)
    assert not CA.start(model, data)  # one core: both halves would share it
    monkeypatch.setattr(CA.os, "cpu_count", lambda: 2)
    monkeypatch.setenv("TDACM_PARALLEL_COMPILE", "0")
    assert not CA.start(model, data)  # the user's opt-out
    monkeypatch.delenv("TDACM_PARALLEL_COMPILE")
    monkeypatch.setenv("NUMBA_DISABLE_JIT", "1")
    assert not CA.start(model, data)
    monkeypatch.delenv("NUMBA_DISABLE_JIT")
    assert CA.start(model, data)
    assert not CA.start(model, data)  # one at a time
    (child,) = fake.started
    assert child.args[1:3] == ["-m", "tdacm.sim.compile_engine"]
    with open(child.args[3], "rb") as f:  # the engine's argument types, handed over
        assert pickle.load(f) == CA.signatures(model, data)
    CA.os.unlink(child.args[3])
    CA.stop()
    assert CA._child is None


def test_this_process_compiles_sense_first_and_loads_the_entry_once_cached(
    monkeypatch, fake, batch
):
    model, data = batch.model, batch.data
    sense, worlds = FakeDispatcher(), FakeDispatcher()
    monkeypatch.setattr(CA.E, "sense", sense)
    monkeypatch.setattr(CA.E, "worlds", worlds)
    monkeypatch.setattr(CA, "saved", lambda dispatcher, sig: False)
    assert CA.start(model, data)
    sig = CA.signatures(model, data)
    CA.first(model, data)
    assert sense.compiled == [sig["sense"]] and worlds.compiled == []
    cached = iter([False, False, True])  # worlds appears in the cache at the third look
    monkeypatch.setattr(CA, "saved", lambda dispatcher, sig: next(cached))
    fake.ends_after = 100
    CA.finish(model, data)
    assert worlds.compiled == [sig["worlds"]]  # loaded from the cache
    child = fake.started[0]
    assert child.polls >= 3 and child.killed and CA._child is None  # waited, then stopped
    CA.os.unlink(child.args[3])
    CA.first(model, data)  # no second process: no-ops
    CA.finish(model, data)
    assert sense.compiled == [sig["sense"]] and worlds.compiled == [sig["worlds"]]


def test_a_second_process_that_ends_early_leaves_the_entry_to_this_one(monkeypatch, fake, batch):
    model, data = batch.model, batch.data
    worlds = FakeDispatcher()
    monkeypatch.setattr(CA.E, "worlds", worlds)
    monkeypatch.setattr(CA, "saved", lambda dispatcher, sig: False)
    assert CA.start(model, data)
    CA.finish(model, data)  # the child ends (fails) without caching worlds
    assert worlds.compiled == [CA.signatures(model, data)["worlds"]] and CA._child is None
    CA.os.unlink(fake.started[0].args[3])


def test_the_second_process_compiles_act_then_the_entry_from_the_handed_types(tmp_path, batch):
    """Its entry point, in this process on the warm cache: act and worlds load for the
    types (sense is cached), the hand-over file is removed."""
    path = tmp_path / "engine.pickle"
    sig = CA.signatures(batch.model, batch.data)
    path.write_bytes(pickle.dumps(sig))
    assert CA._main(str(path)) == 0
    assert not path.exists()
    assert tuple(sig["act"]) in [tuple(s) for s in E.act.signatures]
    assert tuple(sig["worlds"]) in [tuple(s) for s in E.worlds.signatures]


def test_a_batch_built_with_the_second_process_runs_as_one_built_without(monkeypatch, fake):
    """The batch's construction takes the second process's path (a fake one; every kernel
    is cached) and its run is the same bit for bit."""
    plain = _batch(2, 1, 0.2).run()
    monkeypatch.setattr(CA, "saved", lambda dispatcher, sig: False)
    with_ahead = _batch(2, 1, 0.2)
    assert len(fake.started) == 1 and CA._child is None  # started, then waited for
    CA.os.unlink(fake.started[0].args[3])
    res = with_ahead.run()
    np.testing.assert_array_equal(res.rmse, plain.rmse)
    np.testing.assert_array_equal(res.q_final, plain.q_final)

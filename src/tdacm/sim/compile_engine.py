"""The engine's compile in two processes, on a cold numba cache.

The engine's first use compiles its four functions, each with the blocks' compiled steps it
calls (docs/benchmarks.md, "What compiles"): :func:`~tdacm.batch.engine.reset_worlds` when a
:class:`~tdacm.batch.Batch` is built, then the entry :func:`~tdacm.batch.engine.worlds`, whose
type inference compiles :func:`~tdacm.batch.engine.sense` and
:func:`~tdacm.batch.engine.act` before its own body. Numba compiles one function at a time
and holds the GIL meanwhile, so a second thread does not help; a second *process* does, and
hands its result over through numba's on-disk cache (as :mod:`tdacm.loop.precompile` does for
the block loop).

The split, when :func:`~tdacm.sim.batch.build_batch` builds a batch (:func:`start`, :func:`first`,
the batch, then :func:`finish`):

* the second process (this module run as ``python -m tdacm.sim.compile_engine``) compiles
  :func:`~tdacm.batch.engine.act` with the argument types of the engine's own call (the
  plant's, the controller's and the servo's command steps, and the filter's and the touch
  loops', which every world's records carry), then waits until ``sense`` is in the cache and
  compiles the entry :func:`~tdacm.batch.engine.worlds`, which loads it;
* this process compiles :func:`~tdacm.batch.engine.sense`, then
  :func:`~tdacm.batch.engine.reset_worlds` (the batch's reset), then waits until ``worlds`` is
  in the cache and loads it.

The engine's functions take the same argument types for every scenario (records of the same
fields; only the arrays' sizes differ), so one compile serves every batch. The second process
is started only when ``worlds`` is not cached for those types, the machine has at least two
cores, ``TDACM_PARALLEL_COMPILE`` is not ``0`` and the JIT is on. Anything that goes wrong in it
(it fails, it is killed) costs only time: when it has ended, or after :data:`WAIT_LIMIT` s,
this process compiles what is missing itself. ``tests/sim/test_compile_engine.py`` checks that
the types compiled here are those of the engine's calls.
"""

from __future__ import annotations

import atexit
import os
import pickle
import subprocess
import sys
import tempfile
import time

import numba
from numba import types

from .._compiling import add_note, saved
from ..batch import engine as E
from ..loop.precompile import second_process_allowed

#: Longest wait (s) of either process for the other's kernel before compiling it itself.
WAIT_LIMIT = 1800.0
#: How often (s) a process looks in numba's cache for the other's kernel.
POLL = 0.5

#: How long (s) :func:`finish` gives the second process to end before it stops it.
EXIT_WAIT = 60.0

_child: subprocess.Popen | None = None


def signatures(model, data) -> dict:
    """The argument types of the engine's compiled calls for the batch ``model``, ``data``:
    ``reset_worlds`` as :meth:`~tdacm.batch.Batch.reset` calls it, ``sense`` and ``act`` as
    :func:`~tdacm.batch.engine.worlds` calls them (a world's index, its twist row), and
    ``worlds`` as its Python callers do (:func:`~tdacm.batch.engine.step_worlds` and the
    others: one signature)."""
    tm, td = numba.typeof(model), numba.typeof(data)
    i64 = types.int64
    f64 = types.float64
    arr = lambda dtype, ndim: types.Array(dtype, ndim, "C")  # noqa: E731
    return {
        "reset_worlds": (tm, td, arr(types.boolean, 1), arr(f64, 2), arr(f64, 2)),
        "sense": (tm, td, i64),
        "act": (tm, td, i64, arr(f64, 1)),
        "worlds": (
            tm,
            td,
            i64,
            arr(f64, 2),
            arr(types.boolean, 1),
            arr(types.boolean, 1),
            arr(f64, 3),
            arr(f64, 2),
            arr(i64, 2),
            arr(f64, 3),
            i64,
            i64,
        ),
    }


def start(model, data) -> bool:
    """Start the second process (module docstring) if the engine's entry is not compiled for
    this batch's types, there are >= 2 cores and it is allowed; True if it was started (one
    at a time)."""
    global _child
    if _child is not None or not second_process_allowed():
        return False
    sig = signatures(model, data)
    if saved(E.worlds, sig["worlds"]):
        return False
    fd, path = tempfile.mkstemp(prefix="tdacm-engine-", suffix=".pickle")
    with os.fdopen(fd, "wb") as f:
        pickle.dump(sig, f)
    _child = subprocess.Popen(
        [sys.executable, "-m", "tdacm.sim.compile_engine", path],  # the child removes the file
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    _child.started_at = time.perf_counter()
    add_note("in two processes")
    return True


def first(model, data) -> None:
    """This process's share before the batch's reset: ``sense``, which the second process's
    ``worlds`` waits for. A no-op without a second process."""
    if _child is not None:
        E.sense.compile(signatures(model, data)["sense"])


def finish(model, data) -> None:
    """After the batch's reset: wait until the second process has cached ``worlds`` (or has
    ended, or :data:`WAIT_LIMIT` s have passed), then load it (or compile what is missing).
    A no-op without a second process."""
    child = _child
    if child is None:
        return
    sig = signatures(model, data)
    _wait(lambda: child.poll() is None and not saved(E.worlds, sig["worlds"]), child.started_at)
    try:
        child.wait(timeout=EXIT_WAIT)  # it ends once its entry is written
    except subprocess.TimeoutExpired:
        pass
    stop()
    E.worlds.compile(sig["worlds"])


def _wait(pending, since: float) -> None:
    """Sleep while ``pending()``, at most until :data:`WAIT_LIMIT` s after ``since``."""
    while pending() and time.perf_counter() - since < WAIT_LIMIT:
        time.sleep(POLL)


def stop() -> None:
    """End the second process, if one is running (it has nothing left worth waiting for)."""
    global _child
    if _child is not None:
        if _child.poll() is None:
            _child.kill()
        _child.wait()
        _child = None


atexit.register(stop)


def _main(path: str) -> int:
    """The second process: ``act``, then ``worlds`` once this batch's ``sense`` is cached by
    the first process (or after :data:`WAIT_LIMIT` s: then it compiles ``sense`` too)."""
    t0 = time.perf_counter()
    with open(path, "rb") as f:
        sig = pickle.load(f)
    os.unlink(path)
    E.act.compile(tuple(sig["act"]))
    _wait(lambda: not saved(E.sense, sig["sense"]), t0)
    E.worlds.compile(tuple(sig["worlds"]))
    return 0


if __name__ == "__main__":  # pragma: no cover - run as a subprocess by start()
    sys.exit(_main(sys.argv[1]))

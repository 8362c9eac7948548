"""Compile part of the closed loop's numba kernels in a second process on a cold cache.

Why: a first run in a fresh environment spends most of its time compiling numba kernels
(docs/benchmarks.md, "Compile time").
Numba compiles one kernel at a time and holds the GIL while doing it, so a second thread does
not help. A second *process* does. Every kernel compiled with ``cache=True`` is written to
numba's on-disk cache, and the main process then loads it from there instead of compiling it.

The split follows the order in which the main process needs the kernels:

* the main process builds the loop. Building the robot, its gains, the scene and the
  reference view compiles the model's ``coupled_terms`` and its callees, ``input_matrix``,
  ``chain_jacobian``, the corner refinement and the image features (about 30 s);
* meanwhile the second process (this module run as ``python -m tdacm.loop.precompile``)
  compiles what the loop calls from Python only from :func:`~tdacm.sim.assemble.warm_up` on:
  the plant's ``rk4_run`` with ``forward_dynamics`` and the backbone poses (``rk4_run`` last,
  when the main process has cached the rod callees it shares);
* :func:`wait` (called by ``warm_up``) waits until ``rk4_run`` is in the cache, so that it
  loads;
* given the run's scenario (:func:`start`, from ``tdacm run``) the second process is
  :mod:`tdacm.sim.compile_ahead`: after the integrator it builds the same loop and compiles
  its servo's command step and its plant's and controller's steps, which the main process
  reaches last in the first period, after the sensors, perception and the servo's perception.
  Measured on 2 quiet cores, ``tdacm run paper-in-fov --duration 1`` on an empty cache: 162
  and 179 s, against 353 and 292 s with the integrator alone (docs/benchmarks.md, "Cold
  start").

Before a first run the kernels can instead be in the cache already: a wheel carries them
compiled (:mod:`tdacm._jitcache`), and ``make test`` fills the checkout's cache with the jobs
of :mod:`tdacm.bench.compile` (``python -m tdacm.bench.compile fill``).

The second process is started only when the cache is cold (:func:`numba_cache_is_cold`), the
machine has at least two cores and ``TDACM_PARALLEL_COMPILE`` is not ``0``. On one core both halves would share it, and the rod
callees compiled twice would make the run slower. Anything that goes wrong in the second
process (it is killed, it fails) costs nothing but time: the main process then compiles what
is missing itself. The signatures compiled here must be those of the loop's calls (the same
argument types), or the cache entries would not be used. ``tests/loop/test_precompile.py``
checks that the entry point runs and compiles no signature the loop does not use.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

_child: subprocess.Popen | None = None
_started_at = 0.0

#: Longest wait (s) for the second process before the main one compiles on its own.
WAIT_LIMIT = 300.0


def numba_cache_is_cold() -> bool:
    """True when the closed loop's numba kernels are not cached yet for this source and this
    CPU (first use in a checkout or cache folder, or after an edit): they will compile, which
    takes tens of seconds.

    Asks numba's own cache index of ``rk4_run`` and ``coupled_terms``, which every run calls
    (the plant's step, the warm-up's terms), in the folder numba really uses (e.g. a user-wide
    one when the package folder is read-only; entries for this CPU and the current source
    only); falls back to looking for the index files if numba's private cache API is not
    there."""
    try:
        from ..system import kernels as K

        return _uncached((K.rk4_run, K.coupled_terms))
    except Exception:  # pragma: no cover - another numba version's internals
        return _index_files_missing()


def _uncached(kernels) -> bool:
    """Whether any of the dispatchers ``kernels`` lacks an entry for this CPU in numba's cache
    with its data written (numba writes the index first: :func:`tdacm._compiling.saved`;
    raises on another numba version's internals)."""
    from .._compiling import saved_signatures

    return any(not saved_signatures(kernel) for kernel in kernels)


def _index_files_missing() -> bool:
    from importlib.util import find_spec

    spec = find_spec("tdacm.system.kernels")
    if spec is None or spec.origin is None:
        return False
    src = Path(spec.origin)
    cache_dir = os.environ.get("NUMBA_CACHE_DIR")
    for kernel in ("rk4_run", "coupled_terms"):
        pattern = f"kernels.{kernel}-*.nbi"  # numba's index file of a cached function
        if cache_dir:  # numba mirrors the source folder's path under NUMBA_CACHE_DIR
            found = Path(cache_dir).is_dir() and any(Path(cache_dir).rglob(pattern))
        else:
            found = any((src.parent / "__pycache__").glob(pattern))
        if not found:
            return True
    return False


#: The second process's module when the run's scenario is known: the plant's integrator, then
#: the loop's plant and controller steps (:mod:`tdacm.sim.compile_ahead`, a layer above).
AHEAD_MODULE = "tdacm.sim.compile_ahead"
#: How often (s) :func:`wait` looks in numba's cache for the kernels it waits for.
POLL = 0.2


def second_process_allowed() -> bool:
    """Whether a second compiling process may start: two or more cores (on one, both halves
    would share it), the JIT on, and ``TDACM_PARALLEL_COMPILE`` not ``0`` (the user's
    opt-out). Also the engine's (:mod:`tdacm.sim.compile_engine`)."""
    if (os.cpu_count() or 1) < 2:
        return False
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return False
    return os.environ.get("TDACM_PARALLEL_COMPILE", "1") != "0"


def start(scenario=None) -> bool:
    """Start the second compiling process if the cache is cold and there are >= 2 cores;
    True if it was started (at most one per process). With ``scenario`` (the run's
    :class:`~tdacm.sim.scenario.Scenario`, handed over in a temporary pickle) it goes on after
    the plant's integrator with the loop's plant and controller steps, which the main process
    needs last in a period (:data:`AHEAD_MODULE`)."""
    global _child, _started_at
    if _child is not None or not second_process_allowed() or not numba_cache_is_cold():
        return False
    args = [sys.executable, "-m", "tdacm.loop.precompile"]
    if scenario is not None:
        import pickle
        import tempfile

        fd, path = tempfile.mkstemp(prefix="tdacm-scenario-", suffix=".pickle")
        with os.fdopen(fd, "wb") as f:
            pickle.dump(scenario, f)
        args = [sys.executable, "-m", AHEAD_MODULE, path]  # the child removes the file
    _child = subprocess.Popen(
        args,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    _started_at = time.perf_counter()
    return True


def wait(kernels=()) -> None:
    """Wait for the second process, if one was started (no-op otherwise): until each numba
    dispatcher of ``kernels`` has an entry in numba's cache (the child then goes on with what
    it compiles next, and :func:`stop` ends it with the run), or with no ``kernels`` until it
    ends. At most :data:`WAIT_LIMIT` s from its start; then it is stopped and the main process
    compiles what is missing itself."""
    global _child
    if _child is None:
        return
    left = WAIT_LIMIT - (time.perf_counter() - _started_at)
    if kernels:
        while _child.poll() is None and left > 0:
            try:
                if not _uncached(kernels):
                    return
            except Exception:  # pragma: no cover - another numba version's internals
                break
            time.sleep(POLL)
            left = WAIT_LIMIT - (time.perf_counter() - _started_at)
    try:
        _child.wait(timeout=max(1.0, left))
    except subprocess.TimeoutExpired:
        _child.kill()
        _child.wait()
    _child = None


def stop() -> None:
    """Kill the second process, if one was started (the run will not happen)."""
    global _child
    if _child is not None:
        _child.kill()
        _child.wait()
        _child = None


def compile_second_half() -> None:
    """Call once each kernel that the loop first calls from Python in ``warm_up``, with the
    argument types of the loop's own calls (module docstring): the plant's ``rk4_run`` (the
    warm-up's integration) and the backbone poses. The kernels that the blocks' compiled
    steps call (the IBVS law, the controller's law and allocation, the target filter, the
    SE(3) maps) are compiled into those steps, not called through their own entries, so
    compiling them here would be work no run loads."""
    from ..system.kernels import rk4_run
    from ..system.paper import paper_system

    system = paper_system()
    q = np.zeros(system.n)
    if system.floating:
        q[5] = 1.0
    qd = np.zeros(system.n)
    system.backbone(q)
    # Plant.advance and warm_up: (q, qd, u, h, substeps, substeps, model arrays, loads); last,
    # when the main process has cached the model callees it shares with coupled_terms
    rk4_run(q, qd, np.zeros(system.n_u), 1e-4, 1, 1, system.model_arrays, system.loads.packed())


if __name__ == "__main__":  # pragma: no cover - run as a subprocess by start()
    compile_second_half()

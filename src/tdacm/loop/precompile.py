"""Compile half of the closed loop's numba kernels in a second process on a cold cache.

Why: a first run in a fresh environment spends most of its time compiling numba kernels
(docs/benchmarks.md, "Cold start": about 56 s of a 61 s ``tdacm run paper-in-fov --duration 1``).
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
  when the main process has cached the rod callees it shares), while the main process
  compiles the blocks' steps;
* :func:`wait` (called by ``warm_up``) waits for the second process before the first of
  those kernels is called, so they load from the cache.

Measured (2 cores, ``tdacm run paper-in-fov --duration 1`` with an empty cache): 62-67 s in one
process, 42-43 s with the second one; 88.5 s against 60.1 s in a bench run at a slower moment
of the machine (docs/benchmarks.md, "Cold start").

At install time (``make``'s install step) ``python -m tdacm.loop.precompile --install``
(:func:`fill_cache`) runs ``tdacm run paper-in-fov --duration 1`` once, so that numba's on-disk
cache already holds the kernels at the user's first run (docs/benchmarks.md, "Cold start").

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
    index (raises on another numba version's internals)."""
    for kernel in kernels:
        index = kernel._cache._cache_file._load_index()  # {} if stale or missing
        magic = kernel.targetctx.codegen().magic_tuple()
        if not any(key[1] == magic for key in index):
            return True
    return False


def kernels_are_cold(kernels) -> bool:
    """True when any of the numba dispatchers ``kernels`` has no entry in numba's on-disk cache
    for this source and this CPU (its first call will compile), read from numba's own cache
    index; False when that cannot be read (another numba version's internals)."""
    try:
        return _uncached(kernels)
    except Exception:  # pragma: no cover - another numba version's internals
        return False


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


def start() -> bool:
    """Start the second compiling process if the cache is cold and there are >= 2 cores;
    True if it was started (at most one per process)."""
    global _child, _started_at
    if _child is not None or (os.cpu_count() or 1) < 2 or not numba_cache_is_cold():
        return False
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return False
    if os.environ.get("TDACM_PARALLEL_COMPILE", "1") == "0":  # the user's opt-out
        return False
    _child = subprocess.Popen(
        [sys.executable, "-m", "tdacm.loop.precompile"],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    _started_at = time.perf_counter()
    return True


def wait() -> None:
    """Wait for the second process, if one was started (no-op otherwise)."""
    global _child
    if _child is None:
        return
    try:
        _child.wait(timeout=max(1.0, WAIT_LIMIT - (time.perf_counter() - _started_at)))
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


#: What :func:`fill_cache` runs: the README's first command, on one simulated second.
WARM_UP_RUN = ("run", "paper-in-fov", "--duration", "1")
#: What :func:`fill_engine_cache` runs (``make test``'s extra install step), two processes at
#: once: a batch of the engine (:mod:`tdacm.batch`: its one compiled entry, over the block
#: loop's steps :func:`fill_cache` cached) and the vector env with the imitation teacher ...
WARM_UP_ENGINE = (
    "from tdacm.sim.batch import build_batch\n"
    "from tdacm.sim.scenario import load_scenario\n"
    "sc = load_scenario('paper-out-of-fov').with_overrides({'cameras': {'local_renderer': "
    "'analytic', 'global_renderer': 'planar'}, 'ibvs': {'features': 'measured'}}, 'warm-up')\n"
    "b = build_batch(sc, [0, 1], duration=0.2, threads=2)\n"
    "b.run(); b.step(); b.reset()\n"
    # the vector env and the imitation teacher on the robust servo (tdacm.envs)
    "import gymnasium as gym\n"
    "import tdacm.envs\n"
    "from tdacm.envs.teacher import teacher_twists\n"
    "v = gym.make_vec('tdacm/TipServo-v0', num_envs=2, vectorization_mode='vector_entry_point')\n"
    "v.reset(seed=0); teacher_twists(v); v.step(v.action_space.sample()); v.close()\n"
)
#: ... and a one-step identification on the explicit (RK4) and the stiff shooting path
#: (:mod:`tdacm.identify`, kernels of its own)
WARM_UP_IDENTIFY = (
    "from tdacm.identify import identify, synthesize\n"
    "for basis in ('bending:0', 'bending:2'):\n"
    "    rec = synthesize('tendon-steps-loaded', seed=3, duration=3.0).decimated(2)\n"
    "    identify(rec.with_basis(basis), ['E'], segment=1.0, max_nfev=1)\n"
)


def fill_cache(timeout: float = 1800.0) -> int:
    """Fill numba's on-disk cache at install time (the Makefile's install step runs
    ``python -m tdacm.loop.precompile --install``): one ``tdacm run paper-in-fov --duration 1``
    into a temporary folder, which compiles every kernel the scenario runs (in two processes,
    as any cold run) and caches them, so that the user's first run loads them. The batched
    engine, the vector env and identification compile apart (:func:`fill_engine_cache`,
    ``make test``'s step), so that ``make demo`` waits for the demo's kernels only. Returns
    the run's exit code; a failure only costs the user that compile at the first run."""
    import tempfile

    t0 = time.perf_counter()
    print(
        "tdacm: compiling the numba kernels of `tdacm run paper-in-fov` into numba's cache "
        "(once; a minute or more on two cores)...",
        flush=True,
    )
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "tdacm.cli", "-q", *WARM_UP_RUN, "--out", out]
        try:
            proc = subprocess.run(
                cmd, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout
            )
        except subprocess.TimeoutExpired:
            print(f"tdacm: the warm-up run took over {timeout:.0f} s; stopped", flush=True)
            return 1
    if proc.returncode != 0:
        print(f"tdacm: the warm-up run failed:\n{proc.stderr[-2000:]}", flush=True)
    else:
        print(f"tdacm: kernels cached in {time.perf_counter() - t0:.0f} s", flush=True)
    return proc.returncode


def fill_engine_cache(timeout: float = 3600.0) -> int:
    """Fill numba's cache with the batched engine's, the vector env's and identification's
    kernels (``python -m tdacm.loop.precompile --install-engine``, ``make test``'s step after
    :func:`fill_cache`): :data:`WARM_UP_ENGINE` and :data:`WARM_UP_IDENTIFY` in two processes
    at once, so that the tests and a user's first batch load them. Returns 0, or 1 if either
    failed or ran out of time (which only costs that compile at the first use)."""
    t0 = time.perf_counter()
    print(
        "tdacm: compiling the batched engine's, the vector env's and identification's numba "
        "kernels into numba's cache (once; ten minutes or more on two cores)...",
        flush=True,
    )
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", code],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        for code in (WARM_UP_ENGINE, WARM_UP_IDENTIFY)
    ]
    failed = False
    for proc, what in zip(procs, ("the engine and the vector env", "identification"), strict=True):
        try:
            _, err = proc.communicate(timeout=max(1.0, timeout - (time.perf_counter() - t0)))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            print(f"tdacm: compiling {what} took over {timeout:.0f} s; stopped", flush=True)
            failed = True
            continue
        if proc.returncode != 0:
            print(f"tdacm: compiling {what} failed:\n{err[-2000:]}", flush=True)
            failed = True
    if not failed:
        print(f"tdacm: kernels cached in {time.perf_counter() - t0:.0f} s", flush=True)
    return int(failed)


if __name__ == "__main__":  # pragma: no cover - run as a subprocess by start() and make
    if sys.argv[1:] == ["--install"]:
        fill_cache()  # never fails the install: the kernels then compile at the first run
    elif sys.argv[1:] == ["--install-engine"]:
        fill_engine_cache()  # nor this one
    else:
        compile_second_half()

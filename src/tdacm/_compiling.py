"""What compiles says so: one line on stderr before numba compiles the package's kernels, then
a progress bar over them.

numba compiles a kernel at its first call when its cache holds no entry for it (an empty cache,
edited sources, another CPU or numba than the shipped kernels': :mod:`tdacm._jitcache`), which
takes from a second to minutes. :func:`install` (at import) registers a listener of numba's
``numba:compile`` events (``numba.core.event``): the first compile of one of the package's
functions prints ::

    tdacm: compiling the engine's kernels (once, about 90 s; cached afterwards) ...

and draws a bar counted in compiled kernels (each function and argument types numba compiles,
callees included). The job's name, its kernel count and the seconds come from
:func:`compiling`, which the entry points wrap around their work (``tdacm run`` and
:class:`~tdacm.sim.Simulation`, the engine's :func:`~tdacm.sim.batch.build_batch` and
:class:`~tdacm.batch.Batch`, the vector env, :func:`~tdacm.identify.identify`): the estimate
is the kernels of that job (``data/compile_times.json``, measured by ``tdacm bench --compile``)
that the cache does not hold yet. Outside such a scope the line names no job.

The line and the bar follow :func:`tdacm._log.progress_enabled`: shown unless the ``tdacm``
logger is configured above INFO (``tdacm -q``); a library caller that configured nothing sees
them.
"""

from __future__ import annotations

import functools
import json
import os
import sys
from pathlib import Path

from ._jitcache import status as kernel_cache
from ._log import progress_enabled

#: what each job compiles, in the notice
JOBS = {
    "run": "the closed loop's kernels",
    "engine": "the engine's kernels",
    "vector-env": "the vector env's kernels",
    "identify": "identification's kernels",
}
#: the measured compile times of the jobs (``tdacm bench --compile --write-estimates``)
ESTIMATES = Path(__file__).resolve().parent / "data" / "compile_times.json"

#: the current job, its open bar, the jobs announced in this process (``None``: outside a
#: job), whether the listener is registered, notes for the next line
_state: dict = {"job": None, "bar": None, "announced": set(), "installed": False, "notes": []}
_estimates_cache: dict | None = None


def estimates() -> dict:
    """``{job: {"seconds": s, "kernels": [[module, qualname, argument types, s], ...]}}``
    from :data:`ESTIMATES` (empty if missing or unreadable)."""
    global _estimates_cache
    if _estimates_cache is None:
        try:
            _estimates_cache = json.loads(ESTIMATES.read_text()).get("jobs", {})
        except (OSError, ValueError, AttributeError):
            _estimates_cache = {}
    return _estimates_cache


def _dispatcher(module: str, qualname: str):
    obj = sys.modules.get(module)
    for part in qualname.split("."):
        obj = getattr(obj, part, None)
    return obj if hasattr(obj, "overloads") else None


def cached_signatures(disp) -> list:
    """The argument types of the numba dispatcher ``disp`` in numba's on-disk cache for this
    target (source stamp and CPU), read from numba's own index (``[]`` when stale or missing;
    raises on a function without a cache or another numba version's internals)."""
    index = disp._cache._cache_file._load_index()
    magic = disp.targetctx.codegen().magic_tuple()
    return [k[0] for k in index if k[1] == magic]


def saved_signatures(disp) -> list:
    """:func:`cached_signatures` whose data is written: numba writes a new entry's index before
    its data, so an entry in the index alone may still be being written by another process
    (raises like :func:`cached_signatures`)."""
    cache_file = disp._cache._cache_file
    magic = disp.targetctx.codegen().magic_tuple()
    return [key[0] for key, name in cache_file._load_index().items()
            if key[1] == magic and os.path.exists(cache_file._data_path(name))]  # fmt: skip


def saved(disp, sig) -> bool:
    """Whether the numba dispatcher ``disp`` holds ``sig`` (a tuple of argument types) compiled
    in this process or in numba's on-disk cache for this target with its data written
    (:func:`saved_signatures`; ``False`` on another numba version's internals)."""
    if tuple(sig) in disp.overloads:
        return True
    try:
        return tuple(sig) in [tuple(s) for s in saved_signatures(disp)]
    except Exception:  # a function without a cache, another numba's internals
        return False


def is_cached(module: str, qualname: str, types: str, _indexes: dict | None = None) -> bool:
    """Whether the kernel ``module.qualname`` for the argument types ``types`` (their
    ``str``) is compiled in this process or in numba's cache for this target; ``False`` when
    its module is not imported yet or the cache cannot be read."""
    disp = _dispatcher(module, qualname)
    if disp is None:
        return False
    if any(str(k) == types for k in disp.overloads):
        return True
    try:
        key = (module, qualname)
        if _indexes is not None and key in _indexes:
            signatures = _indexes[key]
        else:
            signatures = cached_signatures(disp)
            if _indexes is not None:
                _indexes[key] = signatures
    except Exception:  # a function without a cache, another numba's internals
        return False
    return any(str(sig) == types for sig in signatures)


def remaining(job: str) -> tuple[int, float] | None:
    """``(kernels, seconds)`` of ``job``'s measured compiles that are not cached yet, or
    ``None`` if the job was not measured."""
    entry = estimates().get(job)
    if not entry or not entry.get("kernels"):
        return None
    indexes: dict = {}
    todo = [k for k in entry["kernels"] if not is_cached(k[0], k[1], k[2], indexes)]
    return len(todo), float(sum(k[3] for k in todo))


def _about(seconds: float) -> str:
    if seconds < 10:
        return "a few seconds"
    step = 5 if seconds < 60 else 10 if seconds < 300 else 60
    return f"about {int(round(seconds / step) * step)} s"


def notice_line(job: str | None) -> tuple[str, int | None]:
    """The notice printed before the first compile of ``job`` and the bar's total (kernels
    to compile, ``None`` if unknown)."""
    what = JOBS.get(job, "numba kernels") if job else "numba kernels"
    left = remaining(job) if job else None
    total = None
    parts = ["once"]
    if left is not None and left[0] > 0:
        total = left[0]
        parts.append(f"{total} kernels, {_about(left[1])}")
    parts += _state["notes"]
    parts.append("cached afterwards")
    reason = kernel_cache.get("reason")
    if reason:
        parts.append(reason)
    return f"tdacm: compiling {what} ({'; '.join(parts)}) ...", total


def _ours(event) -> bool:
    disp = (event.data or {}).get("dispatcher")
    module = getattr(getattr(disp, "py_func", None), "__module__", "") or ""
    return module == "tdacm" or module.startswith("tdacm.")


def _open_bar(total):
    from tqdm import tqdm

    return tqdm(total=total, desc="compiling", unit="kernel", file=sys.stderr, leave=True)


def _close_bar() -> None:
    bar = _state["bar"]
    _state["bar"] = None
    if bar is not None:
        if bar.total is not None and bar.n < bar.total:
            bar.total = bar.n  # the rest was in the cache (or compiled by another process)
            bar.refresh()
        bar.close()


def _on_start(event) -> None:
    """The first compile of the package in a scope: the notice (once per job and process;
    outside a job once per process), then a bar until the scope ends."""
    if not _ours(event) or _state["bar"] is not None or not progress_enabled():
        return
    job = _state["job"]
    line, total = notice_line(job)
    if job not in _state["announced"]:
        print(line, file=sys.stderr, flush=True)
        _state["announced"].add(job)
    elif job is None:
        return  # outside a job: one line and one bar per process
    _state["bar"] = _open_bar(total)


def _on_end(event) -> None:
    bar = _state["bar"]
    if bar is None or not _ours(event):
        return
    if bar.total is not None and bar.n >= bar.total:
        bar.total = bar.n + 1  # more than measured: the bar grows
    bar.update(1)


def install() -> None:
    """Register the compile listener with numba (once per process)."""
    if _state["installed"]:
        return
    from numba.core import event

    class _Listener(event.Listener):
        def on_start(self, ev):
            _on_start(ev)

        def on_end(self, ev):
            _on_end(ev)

    event.register("numba:compile", _Listener())
    _state["installed"] = True


def add_note(text: str) -> None:
    """Add ``text`` to the next notice (e.g. ``"in two processes"``)."""
    if text not in _state["notes"]:
        _state["notes"].append(text)


class compiling:  # noqa: N801  (used as a context and a decorator, like contextlib's)
    """The enclosed code is ``job`` (a key of :data:`JOBS`): a compile inside it is announced
    with that job's name and estimate, and its bar is closed on exit. Nested scopes keep the
    outermost job. A context manager, and a decorator (``@compiling("engine")``) that costs
    a dictionary lookup when a scope is already open."""

    def __init__(self, job: str):
        self.job = job
        self.outer = False

    def __enter__(self):
        self.outer = _state["job"] is None
        if self.outer:
            _state["job"] = self.job
        return self

    def __exit__(self, *exc):
        if self.outer:
            _close_bar()
            _state["job"] = None
            _state["notes"] = []
        return False

    def __call__(self, fn):
        job = self.job

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            if _state["job"] is not None:
                return fn(*args, **kwargs)
            with compiling(job):
                return fn(*args, **kwargs)

        return wrapper

"""Where numba caches the package's kernels, and the kernels a wheel ships compiled.

numba compiles each ``cache=True`` function on its first call and keeps the machine code in an
on-disk cache: an index per function (``.nbi``) mapping (argument types, target, bytecode) to
a data file (``.nbc``). Its index is valid for one *source stamp* (numba's default: the hash
of the function's own file) and each entry for one *target*: the CPU name and features the
code was compiled for (``numba.core.codegen.CPUCodegen.magic_tuple``). Object code compiled
for a portable target (``NUMBA_CPU_NAME=generic``, ``NUMBA_CPU_FEATURES`` empty: the
architecture's baseline, SSE2 on x86-64) runs on any CPU of that architecture, so a cache
compiled at build time can travel in the wheel (numba's documentation: a cache "is safe to
share and reuse on a different machine" when the CPU name and features match).

A wheel built by the project's build backend (``buildsys/tdacm_build.py``) carries such a
cache in ``tdacm/_compiled/`` with a ``manifest.json`` stating what it was compiled for: the
hash of the whole package's sources (:func:`package_hash`), the Python, numba and llvmlite
versions, the target triple and the portable CPU. At import (:func:`activate`, the first thing
``tdacm/__init__.py`` does, before any kernel is defined) the package checks the manifest
against this interpreter; when everything matches it

* registers :class:`PackageLocator` ahead of numba's locators: every cached function of the
  package is looked up in ``_compiled/`` (or a user-wide copy of it when the installation is
  read-only), under one source stamp for the whole package. numba does not invalidate a
  cached kernel when a function it calls from *another* file changes; the whole package's
  hash closes that gap for the shipped cache (any edit of any module makes it stale), and
  content rather than paths or modification times keys it;
* runs numba under the manifest's portable target (``NUMBA_CPU_NAME`` and
  ``NUMBA_CPU_FEATURES`` set in the environment, so child processes agree), so that the index
  keys match. This holds for the whole process: other numba code compiled in it is compiled
  for the portable target too. Kernels outside the shipped set (other argument types, other
  scenarios' blocks) compile at their first use, for that target, into the same folder.

When anything does not match (no manifest: a source checkout or an sdist install; another
numba, Python or CPU architecture; edited sources; numba already in use for the host CPU
before ``tdacm`` was imported; ``NUMBA_CPU_NAME`` set to something else;
``TDACM_KERNEL_CACHE=local``), nothing is changed: numba's own caching (``__pycache__`` next
to the sources, or ``NUMBA_CACHE_DIR``), host-tuned, as without a shipped cache;
:data:`status` says why (the compile notice of :mod:`tdacm._compiling` names it).

Building: a process started with ``TDACM_KERNEL_CACHE_BUILD=DIR`` compiles for the portable
target into ``DIR`` with the same locator and stamp (:mod:`tdacm.bench.compile` runs the jobs
and writes the manifest).

This module is the bottom layer (it imports numba and the standard library only).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

#: the package's folder (the locator's sources are the ``.py`` files below it)
PACKAGE_DIR = Path(__file__).resolve().parent
#: the folder of the shipped cache inside the installed package
SHIPPED_DIR = PACKAGE_DIR / "_compiled"
MANIFEST = "manifest.json"
#: the manifest's format (a manifest of another format is not read)
MANIFEST_FORMAT = 1
#: the portable target the wheel's kernels are compiled for: numba's ``NUMBA_CPU_NAME`` and
#: ``NUMBA_CPU_FEATURES`` (``generic`` with no added features: the architecture's baseline)
PORTABLE_CPU = "generic"
PORTABLE_FEATURES = ""
#: ``local``: ignore a shipped cache (numba's own caching, host-tuned); default ``shipped``
ENV_MODE = "TDACM_KERNEL_CACHE"
#: ``DIR``: compile for the portable target into ``DIR`` (the wheel build)
ENV_BUILD = "TDACM_KERNEL_CACHE_BUILD"

#: what :func:`activate` decided: ``mode`` (``"shipped"``, ``"build"`` or ``"local"``),
#: ``root`` (the cache folder of the package's kernels, ``None`` for numba's own), ``reason``
#: (why the shipped kernels are not used, ``None`` when they are or none ship) and
#: ``manifest`` (the shipped manifest, if any)
status: dict = {"mode": "local", "root": None, "reason": None, "manifest": None}


def package_hash(package_dir: Path = PACKAGE_DIR) -> str:
    """SHA-256 of the package's Python sources: every ``*.py`` below ``package_dir`` (not in
    ``__pycache__`` or the shipped cache), by relative path and content; independent of where
    the package is and of modification times."""
    files = []
    for root, dirs, names in os.walk(package_dir):
        dirs[:] = sorted(d for d in dirs if d not in ("__pycache__", SHIPPED_DIR.name))
        files += [Path(root, n) for n in names if n.endswith(".py")]
    h = hashlib.sha256()
    for f in sorted(files, key=lambda p: p.relative_to(package_dir).as_posix()):
        h.update(f.relative_to(package_dir).as_posix().encode() + b"\0")
        h.update(f.read_bytes() + b"\0")
    return h.hexdigest()


def source_stamp(digest: str) -> str:
    """The source stamp of every index of the package's cache (numba compares it on load)."""
    return f"tdacm-sources-{digest}"


def _numba_versions() -> dict:
    import llvmlite
    import numba

    return {"numba": numba.__version__, "llvmlite": llvmlite.__version__}


def _triple() -> str:
    import llvmlite.binding as ll

    return ll.get_process_triple()


def describe_target() -> dict:
    """What a cache compiled in this process is valid for (the manifest's fields)."""
    return {
        "format": MANIFEST_FORMAT,
        "python": "{}.{}".format(*sys.version_info[:2]),
        "cache_tag": sys.implementation.cache_tag,
        **_numba_versions(),
        "triple": _triple(),
        "cpu_name": PORTABLE_CPU,
        "cpu_features": PORTABLE_FEATURES,
    }


def _target_in_use() -> bool:
    """Whether numba's CPU target (its code generator, fixed to a CPU at creation) exists."""
    from numba.core import registry

    return "_toplevel_target_context" in vars(registry.cpu_target)


def _host_has(features: str) -> bool:
    """Whether this CPU has every ``+feature`` of ``features`` (LLVM's names)."""
    wanted = [f[1:] for f in features.split(",") if f.startswith("+")]
    if not wanted:
        return True
    import llvmlite.binding as ll

    try:
        host = ll.get_host_cpu_features()
    except RuntimeError:
        return False
    return all(host.get(f, False) for f in wanted)


def _set_target(cpu: str, features: str) -> None:
    """Compile for ``cpu``/``features`` from now on (environment, so that child processes
    agree, and numba's configuration)."""
    from numba.core import config

    os.environ["NUMBA_CPU_NAME"] = cpu
    os.environ["NUMBA_CPU_FEATURES"] = features
    config.reload_config()


def mismatch(manifest: dict, digest: str | None = None) -> str | None:
    """Why the shipped cache of ``manifest`` cannot serve this process, or ``None``."""
    if manifest.get("format") != MANIFEST_FORMAT:
        return "the shipped kernels' manifest is of another format"
    here = describe_target()
    for key, what in (("python", "Python"), ("numba", "numba"), ("llvmlite", "llvmlite")):
        if manifest.get(key) != here[key]:
            return f"the shipped kernels are for {what} {manifest.get(key)}, this is {here[key]}"
    if manifest.get("cache_tag") != here["cache_tag"]:
        return f"the shipped kernels are for {manifest.get('cache_tag')}"
    if manifest.get("triple") != here["triple"]:
        return f"the shipped kernels are for {manifest.get('triple')}, this CPU is {here['triple']}"
    if not _host_has(manifest.get("cpu_features", "")):
        return f"this CPU lacks features of the shipped kernels ({manifest['cpu_features']})"
    cpu, feats = manifest.get("cpu_name"), manifest.get("cpu_features", "")
    env_cpu = os.environ.get("NUMBA_CPU_NAME")
    if env_cpu is not None and (env_cpu, os.environ.get("NUMBA_CPU_FEATURES", "")) != (cpu, feats):
        return f"NUMBA_CPU_NAME is set to {env_cpu}"
    if (digest or package_hash()) != manifest.get("package_hash"):
        return "the package's sources differ from those the shipped kernels were compiled from"
    if _target_in_use() and env_cpu is None:
        return "numba compiled for this CPU before tdacm was imported"
    return None


def _writable(folder: Path) -> bool:
    try:
        tempfile.TemporaryFile(dir=folder).close()
        return True
    except OSError:
        return False


def user_cache_root() -> Path:
    """Where a read-only installation's shipped cache is copied: ``NUMBA_CACHE_DIR/tdacm`` if
    set, else numba's user-wide cache folder's ``tdacm`` (e.g. ``~/.cache/numba/tdacm``)."""
    from numba.core import config
    from numba.misc.appdirs import AppDirs

    base = config.CACHE_DIR or AppDirs(appname="numba", appauthor=False).user_cache_dir
    return Path(base) / "tdacm"


def _usable_copy(shipped: Path, manifest: dict) -> Path | None:
    """``shipped`` itself if this process can add entries to it, else a copy in
    :func:`user_cache_root` named by the manifest (made once, atomically); ``None`` if
    neither works."""
    if _writable(shipped):
        return shipped
    name = "{}-{}-{}-numba{}".format(
        manifest.get("version", "0"),
        manifest["package_hash"][:16],
        manifest["cache_tag"],
        manifest["numba"],
    )
    target = user_cache_root() / name
    if (target / MANIFEST).is_file():
        return target
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=name + ".", dir=target.parent))
        shutil.copytree(shipped, tmp, dirs_exist_ok=True)
        try:
            tmp.rename(target)
        except OSError:  # another process made it first
            shutil.rmtree(tmp, ignore_errors=True)
        return target if (target / MANIFEST).is_file() else None
    except OSError:
        return None


def _locator_class():
    from numba.core.caching import _CacheLocator

    class PackageLocator(_CacheLocator):
        """numba cache locator of the package's functions: ``root`` / the module's folder
        relative to the package, one source stamp for the whole package
        (:func:`source_stamp` of :func:`package_hash`); other functions are left to numba's
        locators."""

        root: Path | None = None
        stamp: str | None = None

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            rel = Path(py_file).resolve().parent.relative_to(PACKAGE_DIR)
            self._cache_path = str(self.root / rel)

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            return self.stamp

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            if cls.root is None:
                return None
            try:
                Path(py_file).resolve().relative_to(PACKAGE_DIR)
            except (ValueError, OSError):
                return None
            self = cls(py_func, py_file)
            try:
                self.ensure_cache_path()
            except OSError:
                return None
            return self

    return PackageLocator


#: the locator class registered with numba (set by :func:`activate`)
PackageLocator = None


def _register(root: Path, digest: str) -> None:
    global PackageLocator
    from numba.core.caching import CacheImpl

    if PackageLocator is None:
        PackageLocator = _locator_class()
    PackageLocator.root = Path(root)
    PackageLocator.stamp = source_stamp(digest)
    if PackageLocator not in CacheImpl._locator_classes:
        CacheImpl._locator_classes.insert(0, PackageLocator)


def read_manifest(folder: Path = SHIPPED_DIR) -> dict | None:
    try:
        return json.loads((folder / MANIFEST).read_text())
    except (OSError, ValueError):
        return None


def activate() -> dict:
    """Decide where the package's kernels are cached and for which target (module
    docstring); called once at import. Returns :data:`status`."""
    build = os.environ.get(ENV_BUILD)
    if build:
        _set_target(PORTABLE_CPU, PORTABLE_FEATURES)
        Path(build).mkdir(parents=True, exist_ok=True)
        _register(Path(build), package_hash())
        status.update(mode="build", root=Path(build), reason=None, manifest=None)
        return status
    manifest = read_manifest()
    status.update(mode="local", root=None, reason=None, manifest=manifest)
    if manifest is None:
        return status  # a source checkout or an sdist install: numba's own caching
    if os.environ.get(ENV_MODE, "shipped") == "local":
        status["reason"] = f"{ENV_MODE}=local"
        return status
    try:
        reason = mismatch(manifest)
    except Exception as exc:  # pragma: no cover - numba internals of another version
        reason = f"the shipped kernels could not be checked ({exc})"
    if reason is None:
        root = _usable_copy(SHIPPED_DIR, manifest)
        if root is None:
            reason = "neither the installation nor the user's cache folder is writable"
    if reason is not None:
        status["reason"] = reason
        return status
    _set_target(manifest["cpu_name"], manifest.get("cpu_features", ""))
    _register(root, manifest["package_hash"])
    status.update(mode="shipped", root=root)
    return status


def write_manifest(folder: Path, **extra) -> dict:
    """Write ``folder/manifest.json`` for a cache compiled in this (build-mode) process."""
    manifest = {**describe_target(), "package_hash": package_hash(), **extra}
    (Path(folder) / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest

"""A shipped kernel cache (tdacm._jitcache): compiled for the portable target into the
package's ``_compiled/`` folder, it loads in a fresh process from a copy of the package in
another folder, keyed on the sources' content (not paths or modification times); edited
sources, another numba or ``TDACM_KERNEL_CACHE=local`` fall back to numba's own caching."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tdacm import _jitcache

#: a fresh process: where the package was found, what _jitcache decided, numba's target, and
#: the cache hits and misses of one small kernel of the package
_PROBE = (
    "import json, sys, numpy as np, tdacm\n"
    "from numba.core import config\n"
    "from tdacm.lie.se3 import _exp_coefficients as kernel\n"
    "if sys.argv[1] == 'call':\n"
    "    kernel(0.5)\n"
    "s = tdacm._jitcache.status\n"
    "print(json.dumps({'file': tdacm.__file__, 'mode': s['mode'], 'reason': s['reason'],\n"
    "    'cpu': config.CPU_NAME, 'hits': sum(kernel.stats.cache_hits.values()),\n"
    "    'misses': sum(kernel.stats.cache_misses.values())}))\n"
)


def _probe(root: Path, cache: Path, call: bool = True, **env) -> dict:
    e = {k: v for k, v in os.environ.items() if not k.startswith(("TDACM_KERNEL", "NUMBA_CPU"))}
    e.update(PYTHONPATH=str(root), NUMBA_CACHE_DIR=str(cache), **env)
    cmd = [sys.executable, "-c", _PROBE, "call" if call else "status"]
    proc = subprocess.run(cmd, env=e, capture_output=True, text=True, cwd=root)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _copy_package(dest: Path) -> Path:
    shutil.copytree(
        _jitcache.PACKAGE_DIR,
        dest / "tdacm",
        ignore=shutil.ignore_patterns("__pycache__", _jitcache.SHIPPED_DIR.name),
    )
    return dest


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A copy of the package whose ``_compiled/`` holds ``_exp_coefficients`` for the portable target, and
    the manifest of that build."""
    root = _copy_package(tmp_path_factory.mktemp("built"))
    shipped = root / "tdacm" / _jitcache.SHIPPED_DIR.name
    out = _probe(root, tmp_path_factory.mktemp("unused"), TDACM_KERNEL_CACHE_BUILD=str(shipped))
    assert out["mode"] == "build" and out["misses"] == 1 and out["cpu"] == "generic"
    code = "import sys\nfrom tdacm._jitcache import write_manifest\nwrite_manifest(sys.argv[1])"
    env = dict(os.environ, PYTHONPATH=str(root), TDACM_KERNEL_CACHE_BUILD=str(shipped))
    subprocess.run([sys.executable, "-c", code, str(shipped)], env=env, check=True, cwd=root)
    return root, json.loads((shipped / _jitcache.MANIFEST).read_text())


def test_the_shipped_kernel_loads_elsewhere_whatever_the_modification_times(built, tmp_path):
    src, manifest = built
    root = tmp_path / "elsewhere"
    shutil.copytree(src, root)
    assert manifest["package_hash"] == _jitcache.package_hash(root / "tdacm")
    assert (
        manifest["cpu_name"] == "generic"
        and manifest["numba"] == _jitcache._numba_versions()["numba"]
    )
    out = _probe(root, tmp_path / "empty")
    assert out["file"].startswith(str(root)), out
    assert (out["mode"], out["reason"], out["cpu"]) == ("shipped", None, "generic")
    assert (out["hits"], out["misses"]) == (1, 0)
    for f in (root / "tdacm").rglob("*.py"):  # every source a day later: content keys it
        os.utime(f, (f.stat().st_atime + 86400, f.stat().st_mtime + 86400))
    out = _probe(root, tmp_path / "empty2")
    assert (out["mode"], out["hits"], out["misses"]) == ("shipped", 1, 0)
    # ignoring it on request: numba's own caching, host-tuned
    out = _probe(root, tmp_path / "empty3", call=False, TDACM_KERNEL_CACHE="local")
    assert (out["mode"], out["cpu"], out["reason"]) == ("local", None, "TDACM_KERNEL_CACHE=local")


def test_edited_sources_or_another_numba_fall_back_to_numbas_caching(built, tmp_path):
    src, manifest = built
    root = tmp_path / "edited"
    shutil.copytree(src, root)
    cli = root / "tdacm" / "cli.py"  # no kernel in it: the whole package keys the cache
    cli.write_text(cli.read_text() + "\n# an edit\n")
    out = _probe(root, tmp_path / "empty", call=False)
    assert out["mode"] == "local" and out["cpu"] is None
    assert "sources differ" in out["reason"]
    assert "numba 0.1" in _jitcache.mismatch({**manifest, "numba": "0.1"})
    assert "aarch64" in _jitcache.mismatch({**manifest, "triple": "aarch64-unknown-linux-gnu"})
    assert _jitcache.mismatch({**manifest, "format": 0}) is not None


def test_a_read_only_installation_uses_a_copy_in_the_users_cache(built, tmp_path, monkeypatch):
    src, manifest = built
    shipped = src / "tdacm" / _jitcache.SHIPPED_DIR.name
    monkeypatch.setattr(_jitcache, "_writable", lambda folder: False)
    monkeypatch.setattr(_jitcache, "user_cache_root", lambda: tmp_path / "user")
    copy = _jitcache._usable_copy(shipped, manifest)
    assert copy.parent == tmp_path / "user"
    assert sorted(p.relative_to(copy) for p in copy.rglob("*")) == sorted(
        p.relative_to(shipped) for p in shipped.rglob("*")
    )
    assert _jitcache._usable_copy(shipped, manifest) == copy  # made once

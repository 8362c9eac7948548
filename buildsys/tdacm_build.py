"""The project's build backend (PEP 517): setuptools', and a wheel that carries its compiled
kernels.

``python -m build`` (or ``pip install .``, ``pip wheel .``) builds the wheel with setuptools,
then compiles the package's numba kernels into it, so that installing the wheel needs no
compiling for the common case (docs/index.md, "Install"):

1. the plain wheel is unpacked;
2. ``python -m tdacm.bench.compile ship`` (:func:`tdacm.bench.compile.ship`), run on the
   unpacked package, compiles the jobs of :data:`tdacm.bench.compile.JOBS` (``tdacm run
   paper-in-fov``, the batched engine, the vector env, identification) for numba's portable
   target into ``tdacm/_compiled/`` with its ``manifest.json`` (:mod:`tdacm._jitcache`);
3. ``python -m tdacm.bench.compile verify`` runs the jobs again on the unpacked package with
   that cache and fails the build if a kernel of the package still compiles;
4. the wheel is packed again with the tags of what it now carries: machine code for this
   interpreter (``cpXY-cpXY``) and platform (e.g. ``linux_x86_64``).

The build environment therefore needs the package's own dependencies and the ``env`` extra
(the vector env's Gymnasium): :func:`get_requires_for_build_wheel` reads them from
``pyproject.toml``. Compiling takes minutes (about 8 of CPU on 2 cores). ``TDACM_BUILD_KERNELS=0``
in the environment, or ``python -m build -C kernels=skip``, builds the plain wheel (its
kernels compile at their first use, as from a source checkout). Editable installs and the
sdist are setuptools' own.
"""

from __future__ import annotations

import base64
import csv
import hashlib
import io
import os
import subprocess
import sys
import sysconfig
import tempfile
import tomllib
import zipfile
from pathlib import Path

from setuptools import build_meta as _setuptools
from setuptools.build_meta import (  # noqa: F401  (the hooks this backend leaves to setuptools)
    build_editable,
    build_sdist,
    get_requires_for_build_editable,
    get_requires_for_build_sdist,
    prepare_metadata_for_build_editable,
    prepare_metadata_for_build_wheel,
)

#: the optional extras whose packages the compile jobs import (the vector env)
JOB_EXTRAS = ("env",)


def _kernels_wanted(config_settings) -> bool:
    if os.environ.get("TDACM_BUILD_KERNELS", "1") == "0":
        return False
    return (config_settings or {}).get("kernels", "build") != "skip"


def _runtime_requirements() -> list[str]:
    """The package's dependencies and those of :data:`JOB_EXTRAS` (pyproject.toml)."""
    project = tomllib.loads(Path("pyproject.toml").read_text())["project"]
    reqs = list(project.get("dependencies", []))
    for extra in JOB_EXTRAS:
        reqs += [r for r in project.get("optional-dependencies", {}).get(extra, [])
                 if not r.startswith(project["name"])]  # fmt: skip
    return reqs


def get_requires_for_build_wheel(config_settings=None):
    reqs = list(_setuptools.get_requires_for_build_wheel(config_settings))
    if _kernels_wanted(config_settings):
        reqs += _runtime_requirements()
    return reqs


def _platform_tag() -> str:
    tag = f"cp{sys.version_info[0]}{sys.version_info[1]}"
    plat = sysconfig.get_platform().replace("-", "_").replace(".", "_")
    return f"{tag}-{tag}-{plat}"


def _record_line(root: Path, path: Path) -> list[str]:
    data = path.read_bytes()
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return [path.relative_to(root).as_posix(), f"sha256={digest}", str(len(data))]


def _pack(root: Path, wheel_path: Path, tag: str) -> None:
    """Zip the unpacked wheel ``root`` into ``wheel_path`` with the tag ``tag`` and a fresh
    RECORD."""
    dist_info = next(root.glob("*.dist-info"))
    wheel_file = dist_info / "WHEEL"
    lines = [
        ln
        for ln in wheel_file.read_text().splitlines()
        if not ln.startswith(("Tag:", "Root-Is-Purelib:"))
    ]
    wheel_file.write_text("\n".join(lines + ["Root-Is-Purelib: false", f"Tag: {tag}"]) + "\n")
    record = dist_info / "RECORD"
    # the interpreter's bytecode written while the kernels compiled stays out
    files = sorted(
        p
        for p in root.rglob("*")
        if p.is_file() and p != record and "__pycache__" not in p.relative_to(root).parts
    )
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    for p in files:
        writer.writerow(_record_line(root, p))
    writer.writerow([record.relative_to(root).as_posix(), "", ""])
    record.write_text(buf.getvalue())
    # the .dist-info last, as wheels conventionally are
    ordered = [p for p in files if dist_info not in p.parents] + [
        p for p in files if dist_info in p.parents
    ] + [record]  # fmt: skip
    with zipfile.ZipFile(wheel_path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for p in ordered:
            z.write(p, p.relative_to(root).as_posix())


def _run(args: list[str], root: Path) -> None:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(root), *filter(None, [env.get("PYTHONPATH")])])
    env.pop("TDACM_KERNEL_CACHE", None)
    env.pop("NUMBA_CPU_NAME", None)
    env.pop("NUMBA_CPU_FEATURES", None)
    subprocess.run([sys.executable, "-m", "tdacm.bench.compile", *args], env=env, check=True,
                   cwd=root.parent)  # fmt: skip


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    if not _kernels_wanted(config_settings):
        return _setuptools.build_wheel(wheel_directory, config_settings, metadata_directory)
    with tempfile.TemporaryDirectory(prefix="tdacm-wheel-") as tmp:
        plain = Path(tmp) / _setuptools.build_wheel(tmp, config_settings, metadata_directory)
        root = Path(tmp) / "unpacked"
        with zipfile.ZipFile(plain) as z:
            z.extractall(root)
        print("tdacm: compiling the kernels into the wheel (minutes) ...", file=sys.stderr)
        _run(["ship", "--out", str(root / "tdacm" / "_compiled")], root)
        print("tdacm: checking that the wheel's kernels load ...", file=sys.stderr)
        _run(["verify", "--strict"], root)
        name, version = plain.name.split("-")[:2]
        tag = _platform_tag()
        out = Path(wheel_directory) / f"{name}-{version}-{tag}.whl"
        _pack(root, out, tag)
        return out.name

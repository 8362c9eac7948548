"""The build backend (buildsys/tdacm_build.py) without its minutes of compiling: the wheel is
packed again with its compiled kernels, the interpreter's bytecode left out, a platform tag
and a RECORD whose hashes match the files; the build environment gets the jobs' packages."""

from __future__ import annotations

import base64
import csv
import hashlib
import importlib.util
import io
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def backend():
    spec = importlib.util.spec_from_file_location(
        "tdacm_build", ROOT / "buildsys" / "tdacm_build.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_packed_wheel_carries_the_kernels_not_the_bytecode(backend, tmp_path):
    root = tmp_path / "unpacked"
    (root / "tdacm" / "_compiled" / "system").mkdir(parents=True)
    (root / "tdacm" / "__pycache__").mkdir()
    (root / "tdacm" / "__init__.py").write_text("x = 1\n")
    (root / "tdacm" / "__pycache__" / "__init__.cpython-311.pyc").write_bytes(b"\0pyc")
    (root / "tdacm" / "_compiled" / "manifest.json").write_text('{"format": 1}\n')
    (root / "tdacm" / "_compiled" / "system" / "k.f-1.py311.nbi").write_bytes(b"index")
    info = root / "tdacm-0.1.0.dist-info"
    info.mkdir()
    (info / "WHEEL").write_text("Wheel-Version: 1.0\nRoot-Is-Purelib: true\nTag: py3-none-any\n")
    (info / "RECORD").write_text("stale\n")
    tag = "cp311-cp311-linux_x86_64"
    wheel = tmp_path / f"tdacm-0.1.0-{tag}.whl"
    backend._pack(root, wheel, tag)
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        wheel_meta = z.read("tdacm-0.1.0.dist-info/WHEEL").decode()
        record = list(csv.reader(io.StringIO(z.read("tdacm-0.1.0.dist-info/RECORD").decode())))
        data = {n: z.read(n) for n in names}
    assert "tdacm/_compiled/manifest.json" in names
    assert "tdacm/_compiled/system/k.f-1.py311.nbi" in names
    assert not any("__pycache__" in n for n in names)
    assert names[-1] == "tdacm-0.1.0.dist-info/RECORD"
    assert "Root-Is-Purelib: false" in wheel_meta and f"Tag: {tag}" in wheel_meta
    assert "py3-none-any" not in wheel_meta
    assert sorted(r[0] for r in record) == sorted(names)
    for path, digest, size in record:
        if path.endswith("RECORD"):
            assert digest == size == ""
            continue
        want = base64.urlsafe_b64encode(hashlib.sha256(data[path]).digest()).rstrip(b"=")
        assert digest == "sha256=" + want.decode() and int(size) == len(data[path])


def test_the_build_environment_gets_the_jobs_packages_unless_kernels_are_skipped(
    backend, monkeypatch
):
    monkeypatch.chdir(ROOT)
    monkeypatch.delenv("TDACM_BUILD_KERNELS", raising=False)
    reqs = backend._runtime_requirements()
    assert any(r.startswith("numba") for r in reqs) and any(r.startswith("gymnasium") for r in reqs)
    assert backend._kernels_wanted(None) and not backend._kernels_wanted({"kernels": "skip"})
    monkeypatch.setenv("TDACM_BUILD_KERNELS", "0")
    assert not backend._kernels_wanted(None)
    tag = backend._platform_tag()
    assert tag.startswith("cp3") and tag.split("-")[0] == tag.split("-")[1]

"""Optional dependencies: a missing extra is named in the error, from the library and the CLI."""

import importlib
import sys

import pytest

from tdacm import cli
from tdacm._extras import MissingExtraError, require


def test_require_names_the_extra_when_the_module_is_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # `import pyarrow` now raises ImportError
    with pytest.raises(ImportError) as info:
        require("pyarrow", "campaign")
    assert isinstance(info.value, MissingExtraError)
    assert str(info.value).startswith(
        "tdacm campaigns need the 'campaign' extra: pip install 'tdacm[campaign]'"
    )


def test_require_returns_the_module_when_installed():
    assert require("numpy", "campaign") is importlib.import_module("numpy")


def test_env_package_without_gymnasium_names_the_env_extra(monkeypatch):
    for name in [m for m in sys.modules if m == "tdacm.envs" or m.startswith("tdacm.envs.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "gymnasium", None)
    with pytest.raises(MissingExtraError, match=r"pip install 'tdacm\[env\]'"):
        importlib.import_module("tdacm.envs")


def test_cli_reports_a_missing_extra_in_one_error_line(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "rerun", None)
    code = cli.main(["run", "paper-in-fov", "--out", str(tmp_path), "--rerun", "x.rrd"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert err[-1].startswith("error: tdacm Rerun recordings need the 'rerun' extra")


def test_live_without_its_extra_names_it_before_the_run(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "foxglove", None)
    code = cli.main(["run", "paper-in-fov", "--out", str(tmp_path / "o"), "--live", "0"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert err[-1].startswith("error: tdacm live views (Foxglove) need the 'live' extra")
    assert not (tmp_path / "o").exists()

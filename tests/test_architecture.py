"""The layers of the package (``[tool.importlinter]`` in pyproject.toml) are kept: an import
goes down ``lie -> rod/base -> system -> vision, control, estimation -> loop -> sim ->
campaign, envs, viz -> cli``, never up. The same check fails on a violation."""

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import tomli_w

ROOT = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")


def _lint(config: Path) -> subprocess.CompletedProcess:
    # the package of this checkout, not an installed copy elsewhere
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    return subprocess.run(
        [str(LINT), "--no-cache", str(config)], capture_output=True, text=True, cwd=ROOT, env=env
    )


def test_the_layers_are_kept():
    res = _lint(ROOT / "pyproject.toml")
    assert res.returncode == 0, res.stdout[-3000:]
    assert "1 kept, 0 broken" in res.stdout


def test_an_upward_import_breaks_the_contract(tmp_path):
    # the same contract with two layers swapped: loop's real imports of system now run upward
    # (and so do those of the layers in between), and the check must say so
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    layers = config["tool"]["importlinter"]["contracts"][0]["layers"]
    i, j = layers.index("tdacm.loop"), layers.index("tdacm.system")
    layers[i], layers[j] = layers[j], layers[i]
    swapped = tmp_path / "pyproject.toml"
    swapped.write_text(tomli_w.dumps({"tool": config["tool"]}))
    res = _lint(swapped)
    assert res.returncode != 0
    assert "0 kept, 1 broken" in res.stdout
    assert "tdacm.loop is not allowed to import tdacm.system" in res.stdout

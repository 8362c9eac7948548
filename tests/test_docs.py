"""The documentation site builds with ``mkdocs build --strict`` (every link, anchor and API
reference resolves), and the same check fails on a broken link or a bad API reference."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "mkdocs.yml"


def _build(config: Path, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(config), "-d", str(site)],
        capture_output=True,
        text=True,
        cwd=config.parent,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )


def test_docs_site_builds_strict(tmp_path):
    res = _build(CONFIG, tmp_path / "site")
    assert res.returncode == 0, res.stderr[-3000:]
    assert (tmp_path / "site" / "api" / "index.html").is_file()
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    assert "paper_system" in api and "TipServoEnv" in api  # the reference was generated


@pytest.mark.parametrize(
    "page, needle",
    [
        ("See [the model](no-such-page.md).\n", "no-such-page.md"),
        ("See [the model](index.md#no-such-anchor).\n", "no-such-anchor"),
        ("::: tdacm.no_such_module\n", "no_such_module"),
    ],
)
def test_docs_check_fails_on_a_broken_link_or_reference(tmp_path, page, needle):
    """The project's own settings (strict, link validation, the API handler) on a two-page
    site whose second page holds one defect."""
    cfg = yaml.safe_load(CONFIG.read_text())
    cfg.pop("nav", None)
    cfg.pop("repo_url", None)
    cfg["docs_dir"] = str(tmp_path / "docs")
    cfg["plugins"][1]["mkdocstrings"]["handlers"]["python"]["paths"] = [str(ROOT / "src")]
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "index.md").write_text("# Home\n\n[defect](defect.md)\n")
    (tmp_path / "docs" / "defect.md").write_text("# Defect\n\n" + page)
    config = tmp_path / "mkdocs.yml"
    config.write_text(yaml.safe_dump(cfg))
    res = _build(config, tmp_path / "site")
    assert res.returncode != 0
    assert needle in res.stderr


def test_every_scenario_list_names_every_shipped_scenario():
    """The docs' lists of the shipped scenarios (getting started, the README's `tdacm
    scenarios` line, scenarios.md's table and its results) name all of them."""
    from tdacm.sim import list_scenarios

    root = Path(__file__).resolve().parents[1]
    lines = (root / "README.md").read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("tdacm scenarios"))
    readme = lines[k]
    for ln in lines[k + 1 :]:  # the comment's continuation lines
        if not ln.lstrip().startswith("#") or not ln.startswith(" "):
            break
        readme += ln
    started = (root / "docs" / "getting-started.md").read_text()
    started = started[started.index("The shipped scenarios") :].split("\n\n")[0]
    page = (root / "docs" / "scenarios.md").read_text()
    shipped = page[page.index("## The shipped scenarios") :].split("**Results**")[0]
    results = page[page.index("**Results**") :].split("\n\n## ")[0]
    for name in list_scenarios():
        assert name in readme, ("README", name)
        assert f"`{name}`" in started, ("getting-started.md", name)
        assert f"| `{name}` |" in shipped, ("scenarios.md, shipped", name)
        assert f"| `{name}` (" in results, ("scenarios.md, results", name)

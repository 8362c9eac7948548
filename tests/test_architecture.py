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


def _import_graph():
    import grimp

    return grimp.build_graph("tdacm", include_external_packages=False)


def _circles(graph) -> list[set]:
    """The strongly connected components of more than one module of the import graph (every
    import, those inside functions too)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.find_modules_directly_imported_by(v):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)

    sys.setrecursionlimit(10000)
    for v in sorted(graph.modules):
        if v not in index:
            visit(v)
    return out


def test_no_import_circles():
    """No two modules import each other, directly or through others (an import inside a
    function counts): every module's imports go one way."""
    graph = _import_graph()
    # a package imports its own modules from its __init__, which they may import from: not a
    # circle of modules
    circles = [
        c for c in _circles(graph)
        if not any(m == n.rsplit(".", 1)[0] for m in c for n in c if m != n)
        or len([m for m in c if not any(n.startswith(m + ".") for n in c)]) > 1
    ]  # fmt: skip
    assert circles == [], circles


#: the package-internal modules of tdacm's bottom layer, shared by every package by design
_SHARED = {"_jit", "_linalg", "_validate", "_records", "_config", "_extras", "_log", "_timing"}


def private_reads(root: Path) -> list[str]:
    """Where a module reads another package's underscore name: ``from pkg.mod import _name``
    across packages, or ``obj._name`` (``obj`` not ``self``) where ``_name`` is neither
    assigned to ``self`` nor defined in the reading module's own package (the methods of
    NamedTuples, ``_replace``, ``_fields``, ..., are public)."""
    import ast

    src = root / "src" / "tdacm"
    files = sorted(src.rglob("*.py"))
    owned: dict[str, set] = {}
    trees = {}
    for f in files:
        pkg = f.relative_to(src).parts[0].removesuffix(".py")
        tree = ast.parse(f.read_text())
        trees[f] = (pkg, tree)
        names = owned.setdefault(pkg, set())
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.ctx, ast.Store)
                and isinstance(node.value, ast.Name)
                and node.value.id in ("self", "cls")
            ):
                names.add(node.attr)
            elif isinstance(node, ast.FunctionDef | ast.ClassDef):
                names.add(node.name)
            elif isinstance(node, ast.Assign):
                for t in node.targets:
                    if isinstance(t, ast.Name):
                        names.add(t.id)
    public = {"_replace", "_fields", "_asdict", "_make", "_field_defaults"}
    hits = []
    for f, (pkg, tree) in trees.items():
        rel = f.relative_to(root)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                parts = f.relative_to(src).with_suffix("").parts
                if node.level:
                    base = list(parts[: len(parts) - node.level])
                    base += (node.module or "").split(".") if node.module else []
                else:
                    base = (node.module or "").split(".")[1:]
                    if not (node.module or "").startswith("tdacm"):
                        continue
                other = base[0] if base else ""
                for a in node.names:
                    private = a.name.startswith("_") and not a.name.startswith("__")
                    if other in _SHARED or a.name in _SHARED:
                        continue
                    if private and other != pkg:
                        hits.append(f"{rel}:{node.lineno}: from {'.'.join(base)} import {a.name}")
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Load):
                if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                    continue  # an object's own attributes
                name = node.attr
                if not name.startswith("_") or name.startswith("__") or name in public:
                    continue
                if name in _SHARED or name in owned.get(pkg, set()):
                    continue
                hits.append(f"{rel}:{node.lineno}: {ast.unparse(node)}")
    return hits


#: reads of underscore names that are not another tdacm package's, each with its reason: a
#: third-party library's internals the project needs and the library has no public API for,
#: or names defined in generated code (the check reads Python sources, not generated ones)
NOT_TDACM = {
    # mcap_ros2's Writer cannot set a channel's metadata (the latched QoS of /tf_static)
    ("recording/export.py", "w._channel_ids"): "mcap_ros2",
    ("recording/export.py", "w._writer"): "mcap_ros2",
    # numba has no public API to list a dispatcher's cached signatures
    ("_compiling.py", "disp._cache._cache_file._load_index"): "numba",
    ("_compiling.py", "disp._cache._cache_file"): "numba",
    ("_compiling.py", "disp._cache"): "numba",
    # ... nor to tell whether an entry's data is written (tdacm._compiling.saved)
    ("_compiling.py", "cache_file._load_index"): "numba",
    ("_compiling.py", "cache_file._data_path"): "numba",
    # numba's cache locators are a class list with no registration API (tdacm._jitcache)
    ("_jitcache.py", "CacheImpl._locator_classes"): "numba",
    # numba's index-and-data cache file has no public reading API (merging two caches)
    ("bench/compile.py", "a._load_index"): "numba",
    ("bench/compile.py", "b._load_index"): "numba",
    ("bench/compile.py", "a._load_data"): "numba",
    # the functions of the module that tdacm.baselines.codegen generates (same package)
    ("baselines/cc.py", "self.module._evaluate"): "generated",
    ("baselines/cc.py", "self.module._energy"): "generated",
}


def test_no_module_reads_another_packages_underscore_names():
    """A package's underscore names are its own: another package reads a block's parameters
    from its records and public attributes (``params``, ``state``), never its internals."""
    hits = []
    for hit in private_reads(ROOT):
        where, _, expr = hit.partition(": ")
        rel = where.split(":")[0].removeprefix("src/tdacm/")
        if (rel, expr) not in NOT_TDACM:
            hits.append(hit)
    assert hits == []


def test_the_private_read_check_finds_one(tmp_path):
    """The check above fails on a read of another package's underscore attribute."""
    pkg = tmp_path / "src" / "tdacm"
    (pkg / "a").mkdir(parents=True)
    (pkg / "b").mkdir()
    (pkg / "a" / "m.py").write_text("class A:\n    def __init__(self):\n        self._x = 1\n")
    (pkg / "b" / "n.py").write_text("def f(a):\n    return a._x\n")
    assert private_reads(tmp_path) == ["src/tdacm/b/n.py:2: a._x"]


#: the engine's own compiled functions (the loop over worlds, its random streams): a block's
#: logic never lives in tdacm.batch (docs/architecture.md)
ENGINE_FUNCTIONS = {
    "engine": {"_end", "reset_worlds", "sense", "act", "step_worlds", "sense_worlds",
               "act_worlds", "act_sense", "run_worlds", "parallel", "worlds", "_no_log", "_all",
               # the estimator's sensors polled with the world's own random stream (the draws
               # are the sensor steps' inputs), the filter's reset and period called per world
               "_draws", "_poll_pose", "_poll_imu", "_poll_encoders", "_estimate_of",
               "_start_estimation", "_estimate"},
    "random": {"_mix", "_mix_py", "stream_state", "uniform", "normal"},
}  # fmt: skip


def test_the_engine_is_the_loop_over_worlds_only():
    """``tdacm.batch`` holds the engine only: at most 1,200 lines, and its functions are the
    loop over worlds, its streams and its API (a block's step is its module's, called here)."""
    import ast

    folder = ROOT / "src" / "tdacm" / "batch"
    lines = sum(len(f.read_text().splitlines()) for f in folder.glob("*.py"))
    assert lines <= 1200, lines
    for f in folder.glob("*.py"):
        tree = ast.parse(f.read_text())
        compiled = {
            node.name
            for node in tree.body
            if isinstance(node, ast.FunctionDef)
            and any(
                "njit" in ast.unparse(d) or "kernel" in ast.unparse(d) for d in node.decorator_list
            )
        }
        allowed = ENGINE_FUNCTIONS.get(f.stem, set())
        assert compiled <= allowed, (f.name, compiled - allowed)

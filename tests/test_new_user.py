"""What a new user trips on, as a table of cases: bad inputs through the public commands and
the Python API end in a documented way, never a traceback and never a silent acceptance.

* the command line (in process, as ``tdacm ARGS``): exit 2 and one ``error:`` line naming the
  flag, the key or the file (:data:`REFUSED`); an output that cannot be written is refused
  before any work, on every command that writes;
* physically impossible robots and starts, refused at load naming the scenario key
  (:data:`IMPOSSIBLE`);
* the Python API's edges: ``ValueError``/``FileNotFoundError``/``ResetNeeded`` naming the
  argument (:func:`test_api_edges`);
* the feedback of a run that ends: one stderr line naming the termination, progress that ends at
  100 %, a campaign resumed says what it holds.

An unwritable place: ``/proc`` (a virtual file system where nothing can be created, even by
root, so the permission bits alone would not tell).
"""

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from tdacm.cli import main

FAST = '[cameras]\nlocal_renderer = "analytic"\nglobal_renderer = "planar"\nglobal_every = 0\n'
NOWHERE = "/proc/tdacm-cannot-write/out"  # a folder that cannot be created
pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="/proc: Linux")


def _cli(capsys, argv):
    """``(exit code, stdout, stderr)`` of ``tdacm ARGV`` in this process; an exception escaping
    ``main`` (a traceback for a user) fails the test."""
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's own refusals
        code = e.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Inputs a new user may pass by mistake."""
    d = tmp_path_factory.mktemp("inputs")
    (d / "junk.mcap").write_text("this is a text file, not a recording\n")
    (d / "empty.mcap").write_bytes(b"")
    (d / "photo.mcap").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    np.savez(d / "pickled.npz", meta=np.array([{"a": 1}], dtype=object))
    np.savez(d / "plain.npz", x=np.zeros(3))
    (d / "spec.toml").write_text('scenario = "paper-in-fov"\nruns = 1\nduration = 0.04\n')
    (d / "run").mkdir()
    return d


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A tiny run folder of paper-in-fov (0.1 s, analytic C_L)."""
    d = tmp_path_factory.mktemp("run")
    cfg = d / "fast.toml"
    cfg.write_text(FAST)
    assert main(["-q", "run", "paper-in-fov", "--duration", "0.1", "--config", str(cfg),
                 "--out", str(d / "run")]) == 0  # fmt: skip
    return d / "run"


# ------------------------------------------------------------------ refused inputs (exit 2)
#: ``(case, argv with {f} = the inputs folder, {run} = a run folder, needles in the line)``
REFUSED = [
    # outputs that cannot be written: every command that writes, before any work
    ("run --out", ["run", "paper-in-fov", "--out", NOWHERE], ["--out", NOWHERE]),
    (
        "run --rerun",
        ["run", "paper-in-fov", "--out", "{f}/o", "--rerun", NOWHERE + "/r.rrd"],
        ["--rerun"],
    ),
    ("campaign --out", ["campaign", "{f}/spec.toml", "--out", NOWHERE], ["--out"]),
    ("plot --out", ["plot", "{f}/run", "--out", NOWHERE], ["--out"]),
    ("plot of a read-only run folder", ["plot", "/proc/self"], ["RUN_DIR", "--out"]),
    ("replay --out", ["replay", "{f}/run", "--out", NOWHERE + "/r.gif"], ["--out"]),
    ("replay of a read-only run folder", ["replay", "/proc/self"], ["RUN_DIR", "--out"]),
    ("replay --rerun", ["replay", "{f}/run", "--rerun", NOWHERE + "/r.rrd"], ["--rerun"]),
    ("export --mcap", ["export", "{f}/run", "--mcap", NOWHERE + "/r.mcap"], ["--mcap"]),
    ("identify --out", ["identify", "{f}/run", "--params", "E", "--out", NOWHERE], ["--out"]),
    ("bench --out", ["bench", "--out", NOWHERE], ["--out"]),
    ("demo --out", ["demo", "--out", NOWHERE], ["--out"]),
    ("schema --markdown", ["schema", "--markdown", NOWHERE + "/ref.md"], ["--markdown"]),
    ("schema --markdown a folder", ["schema", "--markdown", "{f}"], ["--markdown", "folder"]),
    ("import --out", ["import", "{f}/junk.mcap", "--out", NOWHERE], ["--out"]),
    (
        "replay-recording --out",
        ["replay-recording", "{f}/junk.mcap", "--scenario", "paper-in-fov", "--out", NOWHERE],
        ["--out"],
    ),
    # files that are not what the command reads
    (
        "import a text file",
        ["import", "{f}/junk.mcap", "--out", "{f}/sig"],
        ["junk.mcap", "is not an MCAP recording"],
    ),
    (
        "import an empty file",
        ["import", "{f}/empty.mcap", "--out", "{f}/sig"],
        ["empty.mcap", "empty"],
    ),
    (
        "import a PNG",
        ["import", "{f}/photo.mcap", "--out", "{f}/sig"],
        ["photo.mcap", "not an MCAP"],
    ),
    (
        "identify a text file",
        ["identify", "{f}/junk.mcap", "--params", "E", "--out", "{f}/id"],
        ["junk.mcap", "not an MCAP"],
    ),
    (
        "replay-recording a text file",
        ["replay-recording", "{f}/junk.mcap", "--scenario", "paper-in-fov", "--out", "{f}/rr"],
        ["junk.mcap", "not an MCAP"],
    ),
    ("run a campaign spec", ["run", "{f}/spec.toml", "--out", "{f}/o"], ["spec.toml"]),
    ("campaign a missing spec", ["campaign", "{f}/nope.toml", "--out", "{f}/c"], ["nope.toml"]),
    # identify's flags
    (
        "identify --start E=-5",
        ["identify", "{f}/run", "--params", "E", "--start", "E=-5", "--out", "{f}/id"],
        ["--start", "E must be positive"],
    ),
    (
        "identify --start E=x",
        ["identify", "{f}/run", "--params", "E", "--start", "E=x", "--out", "{f}/id"],
        ["--start", "E must be a number"],
    ),
    (
        "identify --start friction=-1",
        ["identify", "{f}/run", "--params", "friction", "--start", "friction=-1", "--out", "{f}/i"],
        ["--start", "non-negative"],
    ),
    # flags before and after the command
    ("-q and -v", ["-q", "info", "-v"], ["-q/--quiet", "-v/--verbose"]),
]


@pytest.mark.parametrize(("case", "argv", "needles"), REFUSED, ids=[c[0] for c in REFUSED])
def test_refused_with_one_line(capsys, files, case, argv, needles):
    argv = [a.format(f=files) for a in argv]
    code, out, err = _cli(capsys, argv)
    assert code == 2, (case, code, err)
    assert "Traceback" not in err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert lines[-1].startswith(("error:", "tdacm: error:")), err
    if not lines[-1].startswith("tdacm"):  # ours: exactly one line
        assert len(lines) == 1, err
    for n in needles:
        assert n in lines[-1], (case, n, err)
    for leak in ("allow_pickle", "inhomogeneous", "struct.error", "errno", "Errno"):
        assert leak not in err, (case, err)
    assert not Path(NOWHERE).exists()


def test_nothing_is_left_behind_by_the_output_checks(capsys, tmp_path):
    """The writability probe removes its file: a refused run leaves the folder as it was."""
    (tmp_path / "run").mkdir()
    code, _, err = _cli(capsys, ["run", "paper-in-fov", "--out", str(tmp_path / "run"),
                                 "--duration", "0.001"])  # fmt: skip
    assert code == 2 and "--duration" in err
    assert list(tmp_path.rglob("*")) == [tmp_path / "run"]


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        # a campaign spec's union types and list lengths: the key, not pydantic's member tag
        ('batched = "yes"\n', ["batched must be true or false, or 'auto', got 'yes'"]),
        ("batched = 1\n", ["batched must be"]),
        ('[distributions."seed"]\nkind = "fixed"\nvalue = [1, "a"]\n', ["value must be"]),
        ('[distributions."seed"]\nkind = "choice"\nvalues = []\n', ["at least 1 entry, got 0"]),
    ],
)
def test_campaign_spec_messages_name_the_key(capsys, tmp_path, text, needles):
    spec = tmp_path / "spec.toml"
    spec.write_text('scenario = "paper-in-fov"\nruns = 1\n' + text)
    code, _, err = _cli(capsys, ["campaign", str(spec), "--out", str(tmp_path / "c")])
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    for n in needles:
        assert n in err
    for leak in (".bool ", ".float ", "list[float]", "literal[", "1 entries"):
        assert leak not in err


def test_ragged_tendon_offsets_name_the_key(capsys, tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[robot.tendons]\noffsets = [[0.01, 0.0], [0.0, 0.01], [-0.01]]\n")
    code, _, err = _cli(capsys, ["run", "paper-in-fov", "--config", str(cfg),
                                 "--out", str(tmp_path / "o")])  # fmt: skip
    assert code == 2 and "robot.tendons" in err and "inhomogeneous" not in err, err


# ------------------------------------------------------------------ physically impossible
#: ``(case, config text, needles)``: refused at load naming the key, nothing run
IMPOSSIBLE = [
    (
        "tendons on the backbone",
        "[robot.tendons]\noffsets = [[0, 0], [0, 0], [0, 0], [0, 0]]\n",
        ["robot.tendons.offsets", "no moment arm"],
    ),
    (
        "tendons on one side",
        "[robot.tendons]\noffsets = [[0.01, 0.0], [0.007, 0.007], [0.007, -0.007]]\n",
        ["robot.tendons.offsets", "one side"],
    ),
    (
        "drone below the ground",
        "[initial]\nq = [0.0, 0.0, 0.1745, -0.5, 0.5, -1.0, -0.3, -0.4]\n",
        ["initial.q", "drone", "below the ground"],
    ),
    (
        "rod below the ground",
        "[initial]\nq = [0.0, 0.0, 0.1745, -0.5, 0.5, 0.6, -0.3, -0.4]\n",
        ["initial.q", "rod", "below the ground"],
    ),
    (
        "target in neither camera's view",
        "[initial]\nq = [0.0, 0.0, 0.1745, 3.0, 3.0, 5.0, -0.3, -0.4]\n",
        ["initial.q", "neither camera"],
    ),
]


@pytest.mark.parametrize(("case", "text", "needles"), IMPOSSIBLE, ids=[c[0] for c in IMPOSSIBLE])
def test_impossible_robot_or_start_is_refused_at_load(capsys, tmp_path, case, text, needles):
    cfg = tmp_path / "c.toml"
    cfg.write_text(FAST + text)
    code, _, err = _cli(capsys, ["run", "paper-in-fov", "--config", str(cfg),
                                 "--out", str(tmp_path / "o")])  # fmt: skip
    assert code == 2, (case, err)
    assert len(err.strip().splitlines()) == 1 and err.startswith("error:"), err
    for n in needles:
        assert n in err, (case, n, err)
    assert not (tmp_path / "o").exists()


def test_every_shipped_scenario_passes_the_load_checks():
    from tdacm.sim import build_world, list_scenarios, load_scenario

    for name in list_scenarios():
        build_world(load_scenario(name))  # raises ScenarioError naming the key otherwise


def test_tendons_around_the_backbone_are_accepted():
    from tdacm.sim.robot import moment_arm_problem

    assert moment_arm_problem([[0.01, 0], [-0.01, 0], [0, 0.01], [0, -0.01]]) is None
    assert moment_arm_problem([[0.012, 0], [-0.006, 0.0104], [-0.006, -0.0104]]) is None
    assert moment_arm_problem([[0.01, 0], [-0.01, 0], [0.0, 0.0]]) is None  # planar: both ways
    assert "one side" in moment_arm_problem([[0.01, 0], [0.0, 0.01], [0.01, 0.001]])
    assert "no moment arm" in moment_arm_problem(np.zeros((4, 2)))


# ------------------------------------------------------------------ the run folder commands
def test_plot_kinds_with_no_data_in_the_run(capsys, run_dir):
    code, _, err = _cli(capsys, ["plot", str(run_dir), "--kinds", "arms", "--formats", "png"])
    assert code == 2 and "--kinds arms" in err and "[[robot.arms]]" in err, err
    code, _, err = _cli(capsys, ["plot", str(run_dir), "--kinds", "arms,actuation",
                                 "--formats", "png"])  # fmt: skip
    assert code == 0 and "not drawn (no data in this run): arms" in err, err


def test_a_pickled_npz_is_named_not_numpy_advice(tmp_path, files):
    from tdacm.loop.policy import PolicyError, load_policy
    from tdacm.sim.outputs import RunDirError, load_run

    with pytest.raises(PolicyError, match="Python objects") as e:
        load_policy(files / "pickled.npz")
    assert "allow_pickle" not in str(e.value)
    with pytest.raises(PolicyError, match="no 'meta' array"):
        load_policy(files / "plain.npz")
    (tmp_path / "timeseries.npz").write_bytes((files / "pickled.npz").read_bytes())
    with pytest.raises(RunDirError, match="Python objects") as e:
        load_run(tmp_path)
    assert "allow_pickle" not in str(e.value)


def test_quiet_and_verbose_after_the_command(capsys, tmp_path):
    code, out, err = _cli(capsys, ["info", "-q"])
    assert code == 0 and "n = 8 generalized coordinates" in out
    code, out, err = _cli(capsys, ["scenarios", "--verbose"])
    assert code == 0 and "dual-squeeze" in out


def test_a_shipped_name_wins_over_a_folder_of_that_name(tmp_path, monkeypatch, capsys):
    from tdacm.sim import ScenarioError, load_scenario

    (
        tmp_path / "touch-target"
    ).mkdir()  # e.g. written by `tdacm run touch-target --out touch-target`
    (tmp_path / "touch-target" / "scenario.toml").write_text("not toml [")
    monkeypatch.chdir(tmp_path)
    assert load_scenario("touch-target").source == "scenario touch-target"
    with pytest.raises(ScenarioError, match=r"directory.*touch-target/scenario.toml"):
        load_scenario("./touch-target")
    code, _, err = _cli(capsys, ["run", "touch-target", "--duration", "0.001"])
    assert code == 2 and "--duration" in err  # the scenario loaded: the next check speaks


# ------------------------------------------------------------------ the Python API's edges
def test_api_edges(tmp_path):
    from gymnasium.error import ResetNeeded

    from tdacm.campaign import read_results
    from tdacm.envs import TipServoEnv
    from tdacm.sim import build_loop, load_scenario

    sc = load_scenario("paper-in-fov").with_overrides(
        {"cameras": {"local_renderer": "analytic", "global_renderer": "planar"}}, "fast"
    )
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        build_loop(sc, seed=-1)
    with pytest.raises(ValueError, match="seed"):
        build_loop(sc, seed=1.5)
    loop = build_loop(sc, seed=0).loop
    for bad in (float("nan"), -1, 0, float("inf"), "3"):
        with pytest.raises(ValueError, match="duration must be a finite positive number"):
            loop.run(bad)
    with pytest.raises(FileNotFoundError, match="nowhere"):
        read_results(tmp_path / "nowhere")
    assert len(read_results(tmp_path)) == 0  # a folder that holds no run yet: empty
    env = TipServoEnv(scenario="paper-in-fov", overrides={"cameras": {"global_renderer": "planar"}})
    try:
        with pytest.raises(ResetNeeded):
            env.step(np.zeros(6))
        env.reset(seed=0)
        with pytest.warns(UserWarning, match="clipped"):
            env.step(100 * np.ones(6, np.float32))
        with pytest.raises(ValueError, match="finite"):
            env.step(np.full(6, np.nan))
    finally:
        env.close()


# ------------------------------------------------------------------ feedback
def test_an_early_ending_prints_its_termination_and_reason_even_quiet(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text(FAST + "[sensors]\npixel_noise = 3\n[ibvs]\nfeatures = \"measured\"\n"
                   "[safety]\ngrowth_limit = 1e-6\nmin_increase = 0\ngrace = 0\n")  # fmt: skip
    code, out, err = _cli(capsys, ["run", "paper-in-fov", "--config", str(cfg), "--duration",
                                   "0.4", "--out", str(tmp_path / "o"), "-q"])  # fmt: skip
    summary = json.loads(out)
    assert code == 1 and summary["termination"] == "safety"
    assert err.strip().splitlines() == [f"safety: {summary['termination_reason']}"]


def test_progress_ends_at_100_and_its_clock_starts_after_the_first_step(capsys, monkeypatch):
    import time

    from tdacm import _log

    monkeypatch.setattr(_log, "progress_enabled", lambda: True)
    bar = _log.Progress(5, "test")
    time.sleep(0.3)  # the first step: a compilation
    bar.to(1)
    assert bar.bar._time() - bar.bar.start_t < 0.2  # the rate starts after it
    for k in range(2, 6):
        bar.to(k)
    bar.close(complete=True)
    assert bar.bar.n == 5
    last = re.split(r"[\r\n]", capsys.readouterr().err.strip())[-1]
    assert "100%" in last and "5/5" in last


def test_a_run_bar_reaches_100(tmp_path, capsys, monkeypatch):
    from tdacm import _log
    from tdacm.sim import build_loop, load_scenario

    monkeypatch.setattr(_log, "progress_enabled", lambda: True)
    sc = load_scenario("paper-in-fov").with_overrides(
        {"cameras": {"local_renderer": "analytic", "global_renderer": "planar"}}, "fast"
    )
    build_loop(sc, seed=0).loop.run(0.1, progress=True)
    last = re.split(r"[\r\n]", capsys.readouterr().err.strip())[-1]
    assert "100%" in last and "6/6" in last, last


def test_a_resumed_campaign_says_what_it_holds(tmp_path, capsys):
    from tdacm.campaign import load_spec
    from tdacm.campaign.runner import _prepare_out
    from tdacm.campaign.store import write_row

    spec_file = tmp_path / "spec.toml"
    spec_file.write_text('scenario = "paper-in-fov"\nruns = 1\nduration = 0.04\n')
    out = tmp_path / "c"
    store = _prepare_out(load_spec(spec_file), out)
    write_row(store, {"run": 0, "seed": 1, "status": "ok", "success": True, "final_rmse": 0.5,
                      "initial_rmse": 0.4, "overrides": ""})  # fmt: skip
    code, _, err = _cli(capsys, ["campaign", str(spec_file), "--out", str(out)])
    assert "1 of 1 runs already stored" in err and "nothing to run" in err, err
    assert code == 0 and "Traceback" not in err
    md = (out / "report.md").read_text()
    assert "| 0 | 1 | ok | 0.5 |" in md  # RMSEs in a few digits, not 17


def test_identify_marks_a_parameter_at_its_search_bound():
    from tdacm.identify.fit import SEARCH_FACTOR, Identification

    res = Identification(
        ["E", "damping"], {"E": 1.5e11, "damping": 90.0}, {"E": 0.0, "damping": 3.0},
        {"E": 0.0, "damping": 0.033}, np.eye(2), {"E": 5e10, "damping": 100.0},
        {"E": 5e10, "damping": 100.0}, 1.0, 1.0, 10, 3, 0.1, True, "ok", at_bound=["E"],
    )  # fmt: skip
    table = res.table()
    e_row = next(ln for ln in table.splitlines() if ln.startswith("E "))
    assert "at bound" in e_row and "0.00%" not in e_row
    assert "3.30%" in next(ln for ln in table.splitlines() if ln.startswith("damping"))
    assert f"a factor {SEARCH_FACTOR:g} from the start" in table
    assert res.to_dict()["parameters"]["E"]["at_search_bound"] is True


def test_sensitivity_only_for_keys_that_vary():
    import pandas as pd

    from tdacm.campaign.report import sampled_values

    rows = [{"ibvs": {"mode": "mean", "gain": g, "v": [1.0, g]}} for g in (0.5, 0.5, 0.7)]
    df = pd.DataFrame({"overrides": [json.dumps(r) for r in rows]})
    assert sampled_values(df, "ibvs.mode") == {}  # one category for every run
    assert list(sampled_values(df, "ibvs.gain")) == ["ibvs.gain"]
    assert list(sampled_values(df, "ibvs.v")) == ["ibvs.v[1]"]  # the component that varies
    one = pd.DataFrame({"overrides": [json.dumps(rows[0])]})
    assert sampled_values(one, "ibvs.gain") == {}  # a single run: nothing varies

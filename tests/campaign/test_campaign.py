"""Campaign specs, seeding, the failure path, resume, and local vs separate scheduler."""

import json

import numpy as np
import pytest

from tdacm.campaign import (
    CampaignSpecError,
    execute_run,
    parse_spec,
    read_results,
    run_campaign,
    sample_overrides,
    wilson_interval,
)
from tdacm.sim.scenario import load_scenario

SPEC = """
scenario = "paper-in-fov"
runs = 4
seed = 7
duration = 0.06
[distributions]
"initial.q" = { kind = "normal", std = [0, 0, 0.02, 0.05, 0.05, 0.05, 0.02, 0.02] }
"model.perturbation" = { kind = "uniform", low = 0.05, high = 0.15 }
"""


@pytest.fixture(scope="module")
def scenario_data():
    return load_scenario("paper-in-fov").data


def test_spec_validation_errors(scenario_data):
    def bad(text, match):
        with pytest.raises(CampaignSpecError, match=match):
            parse_spec(text, "spec.toml", scenario_data)

    bad("runs = 3", "scenario is required")
    bad('scenario = "paper-in-fov"\nruns = 0', "runs must be >= 1, got 0")
    bad('scenario = "paper-in-fov"\nruns = 2\nworkers = 3', "unknown key workers")
    bad(
        'scenario = "paper-in-fov"\nruns = 2\n[distributions]\n"initial.q" = { kind = "gauss", std = 1 }',
        "kind",
    )
    bad(
        'scenario = "paper-in-fov"\nruns = 2\n[distributions]\n"initial.q" = { kind = "normal", std = [1, 2] }',
        "8 entries",
    )
    bad(
        'scenario = "paper-in-fov"\nruns = 2\n[distributions]\n"model.nope" = { kind = "fixed", value = 1 }',
        "no key 'nope'",
    )
    bad(
        'scenario = "paper-in-fov"\nruns = 2\n[distributions]\n"cams.x" = { kind = "fixed", value = 1 }',
        "no section",
    )
    bad(
        'scenario = "paper-in-fov"\nruns = 2\n[distributions]\n"model.perturbation" = { kind = "uniform", low = 1, high = 0 }',
        "high must be >= low",
    )
    bad("scenario = [", "invalid TOML")


def test_seeding_is_reproducible_and_distinct(scenario_data):
    spec = parse_spec(SPEC, "s", scenario_data)
    seeds = spec.run_seeds()
    assert np.array_equal(seeds, parse_spec(SPEC, "s", scenario_data).run_seeds())
    assert len(set(seeds.tolist())) == spec.runs
    a = sample_overrides(spec, scenario_data, int(seeds[0]))
    assert a == sample_overrides(spec, scenario_data, int(seeds[0]))
    assert a != sample_overrides(spec, scenario_data, int(seeds[1]))
    assert 0.05 <= a["model"]["perturbation"] <= 0.15
    dq = np.array(a["initial"]["q"]) - np.array(scenario_data["initial"]["q"])
    assert dq[0] == 0.0 and np.abs(dq[3]) > 0


def test_failing_run_becomes_an_error_row(scenario_data):
    spec = parse_spec(
        'scenario = "paper-in-fov"\nruns = 1\nduration = 0.04\n[distributions]\n'
        '"robot.rod.basis" = { kind = "fixed", value = "bogus:1" }',
        "s",
        scenario_data,
    )
    row = execute_run(spec.__dict__, 0, 123)
    assert row["status"] == "error" and row["success"] is False
    assert "robot.rod.basis = 'bogus:1'" in row["error"]
    with pytest.raises(CampaignSpecError, match="model.perturbation must be in"):  # on load
        parse_spec(
            'scenario = "paper-in-fov"\nruns = 1\n[distributions]\n'
            '"model.perturbation" = { kind = "fixed", value = -3.0 }',
            "s",
            scenario_data,
        )


def test_wilson_interval():
    lo, hi = wilson_interval(95, 100)
    assert 0.88 < lo < 0.9 and 0.97 < hi < 0.99
    assert wilson_interval(0, 10)[0] == 0.0


def test_interrupted_campaign_resumes_and_scheduler_gives_same_rows(tmp_path, scenario_data):
    from dask.distributed import LocalCluster

    spec_path = tmp_path / "spec.toml"
    spec_path.write_text(SPEC)
    out = tmp_path / "local"
    # "kill" after 2 runs, then resume: exactly 4 rows, the first two untouched
    run_campaign(spec_path, out, workers=2, progress=False, max_runs=2)
    first = read_results(out)
    assert len(first) == 2
    report = run_campaign(spec_path, out, workers=2, progress=False)
    rows = read_results(out)
    assert len(rows) == 4 and sorted(rows["run"]) == [0, 1, 2, 3]
    assert report["runs_stored"] == 4 and report["complete"]
    kept = rows.set_index("run").loc[first["run"]]
    assert np.array_equal(kept["run_wall_s"].to_numpy(), first["run_wall_s"].to_numpy())
    assert (out / "report.md").exists() and (out / "report.png").exists()
    # the same spec on a scheduler started separately (loopback) gives the same per-run results
    with LocalCluster(
        n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None
    ) as cluster:
        run_campaign(
            spec_path, tmp_path / "remote", scheduler=cluster.scheduler_address, progress=False
        )
    remote = read_results(tmp_path / "remote")
    for col in ("seed", "overrides", "final_rmse", "initial_rmse", "status"):
        assert remote[col].tolist() == rows[col].tolist(), col


def test_parquet_store_has_a_fixed_schema(tmp_path):
    """pandas.read_parquet(OUT/results) works when a metric is None in one row and a number in
    another (pyarrow otherwise fails with 'Unsupported cast from double to null')."""
    import pandas as pd

    from tdacm.campaign.store import COLUMNS, write_row

    store = tmp_path / "results"
    store.mkdir()
    write_row(store, {"run": 0, "seed": 1, "status": "ok", "success": False,
                      "time_to_0.01": None, "final_rmse": 0.2, "terminated": True,
                      "termination_reason": "safety", "overrides": "{}"})  # fmt: skip
    write_row(store, {"run": 1, "seed": 2, "status": "ok", "success": True,
                      "time_to_0.01": 3.5, "final_rmse": 0.005, "terminated": False})  # fmt: skip
    write_row(store, {"run": 2, "seed": 3, "status": "error", "success": False,
                      "error": "ValueError: x"})  # fmt: skip
    (store / ".run-000003.parquet.tmp").write_bytes(b"partial")  # an interrupted write
    df = pd.read_parquet(store)
    assert len(df) == 3 and list(df.columns) == list(COLUMNS)
    df = df.sort_values("run")
    assert np.isnan(df["time_to_0.01"].iloc[0]) and df["time_to_0.01"].iloc[1] == 3.5
    rr = read_results(tmp_path)
    assert rr["run"].tolist() == [0, 1, 2] and rr["status"].tolist() == ["ok", "ok", "error"]


def test_sampling_initial_qd_reaches_the_run(scenario_data):
    spec = parse_spec(
        'scenario = "paper-in-fov"\nruns = 1\nduration = 0.04\n[distributions]\n'
        '"initial.qd" = { kind = "normal", std = [0, 0, 0, 0.01, 0.01, 0.01, 0.01, 0.01] }',
        "s",
        scenario_data,
    )
    over = sample_overrides(spec, scenario_data, 5)
    assert len(over["initial"]["qd"]) == 8 and over["initial"]["qd"][0] == 0.0
    row = execute_run(spec.__dict__, 0, 5)
    assert row["status"] == "ok", row["error"]


def test_sampling_an_unset_key_is_rejected(scenario_data):
    with pytest.raises(CampaignSpecError, match="expect.initial_in_local_fov"):
        parse_spec(
            'scenario = "paper-in-fov"\nruns = 1\n[distributions]\n'
            '"expect.initial_in_local_fov" = { kind = "fixed", value = 1 }',
            "s",
            {**scenario_data, "expect": {"initial_in_local_fov": None}},
        )


def test_campaign_cli_exits_nonzero_when_every_run_errors(tmp_path, capsys):
    from tdacm.cli import main

    spec = tmp_path / "spec.toml"
    spec.write_text(
        'scenario = "paper-in-fov"\nruns = 2\nduration = 0.04\n[distributions]\n'
        '"robot.rod.basis" = { kind = "fixed", value = "bogus:1" }\n'
    )
    code = main(["campaign", str(spec), "--workers", "1", "--out", str(tmp_path / "c")])
    cap = capsys.readouterr()
    assert code == 1
    assert "every run (2) raised an error" in cap.err


def test_ctrl_c_stops_a_campaign_cleanly_keeping_stored_rows(tmp_path):
    import json
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2] / "src")}
    spec = tmp_path / "spec.toml"
    # enough runs that the campaign is still going when Ctrl-C arrives: a warm cache runs
    # these short runs at ~25 a second
    spec.write_text(SPEC.replace("runs = 4", "runs = 2000"))
    cmd = [sys.executable, "-m", "tdacm.cli", "campaign", str(spec), "--workers", "1",
           "--out", str(tmp_path / "c")]  # fmt: skip
    # SIGINT at its default in the child, as in a terminal (a shell's background job, e.g. a
    # CI runner, starts it ignored, and Python then never raises KeyboardInterrupt)
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    store = tmp_path / "c" / "results"
    t0 = time.time()
    while time.time() - t0 < 180 and proc.poll() is None:
        if store.is_dir() and len(list(store.glob("run-*.parquet"))) >= 1:
            break
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGINT)  # like Ctrl-C in a terminal: the whole process group
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.startswith("interrupted")]
    assert len(lines) == 1 and "resume" in lines[0]
    n = len(read_results(tmp_path / "c"))
    assert 1 <= n < 2000
    assert json.loads((tmp_path / "c" / "campaign.json").read_text())["fingerprint"]


def test_spec_samples_nested_robot_keys_and_fixes_text_keys():
    """Dotted paths of any depth ([robot.rod] length) and string/boolean parameters (kinds
    'fixed' and 'choice' only), with the key named when a path is wrong."""
    from tdacm.campaign.spec import to_toml
    from tdacm.sim.scenario import parse_scenario

    sc = load_scenario("paper-in-fov")
    text = (
        'scenario = "paper-in-fov"\nruns = 2\n[distributions]\n'
        '"robot.rod.length" = { kind = "uniform", low = 0.9, high = 1.1 }\n'
        '"ibvs.mode" = { kind = "choice", values = ["mean", "current"] }\n'
        '"safety.enabled" = { kind = "fixed", value = false }\n'
    )
    spec = parse_spec(text, "t", sc.data)
    assert parse_spec(text, "t").distributions == spec.distributions  # the first pass agrees
    o = sample_overrides(spec, sc.data, 5)
    assert 0.9 <= o["robot"]["rod"]["length"] <= 1.1
    assert o["ibvs"]["mode"] in ("mean", "current") and o["safety"]["enabled"] is False
    again = sc.with_overrides(o, "run")
    assert again["robot"]["rod"]["length"] == o["robot"]["rod"]["length"]
    # the per-run config file round-trips
    assert parse_scenario(to_toml({"name": "x", **again.data}), "rt")["robot"] == again["robot"]
    head = 'scenario = "paper-in-fov"\nruns = 1\n[distributions]\n'
    for bad, match in [
        ('"robot.rod.lenght" = { kind = "fixed", value = 1.0 }', "has no key 'lenght'"),
        ('"ibvs.mode" = { kind = "normal", std = 1 }', "use kind 'fixed' or 'choice'"),
        ('"robot.rod" = { kind = "fixed", value = 1 }', r"\[robot.rod\] is a section"),
        ('"ibvs.mode" = { kind = "fixed", value = 3 }', "give str value"),
    ]:
        with pytest.raises(CampaignSpecError, match=match):
            parse_spec(head + bad, "t", sc.data)


def test_success_window_criterion(scenario_data):
    """success_window judges the RMS of the last seconds, not the last sample; unset keeps
    the last-sample criterion and the fingerprint of older specs."""
    from tdacm.campaign.spec import succeeded
    from tdacm.sim.runner import late_rmse

    base = 'scenario = "paper-in-fov"\nruns = 2\nduration = 3.0\n'
    plain = parse_spec(base, "s", scenario_data)
    windowed = parse_spec(base + "success_window = 1.0\n", "s", scenario_data)
    assert plain.success_window is None and windowed.success_window == 1.0
    assert "success_window" not in plain.as_dict()
    assert plain.fingerprint() != windowed.fingerprint()
    t = np.arange(0.0, 3.0 + 1e-9, 0.02)
    # settled at 0.005 but one last sample at 0.012: a failure by the sample, not by the window
    rmse = np.full(t.size, 0.005)
    rmse[-1] = 0.012
    arrays = {"t": t, "rmse": rmse}
    summary = {"final_rmse": 0.012, "terminated": False}
    assert not succeeded(plain, arrays, summary)
    assert succeeded(windowed, arrays, summary)
    last = rmse[t >= 2.0 - 1e-9]
    assert late_rmse(t, rmse, 1.0) == pytest.approx(np.sqrt(np.mean(last**2)), rel=1e-15)
    # oscillating through 0.01 in the last second: the window fails even if the end is low
    rmse2 = 0.005 + 0.012 * np.abs(np.sin(2 * np.pi * 3 * t))
    rmse2[-1] = 0.004
    arrays2 = {"t": t, "rmse": rmse2}
    summary2 = {"final_rmse": 0.004, "terminated": False}
    assert succeeded(plain, arrays2, summary2) and not succeeded(windowed, arrays2, summary2)
    assert not succeeded(windowed, arrays, {**summary, "terminated": True})
    for bad, match in (("success_window = 0.0", "success_window must be > 0"),
                       ("success_window = 5.0", "must not exceed duration")):  # fmt: skip
        with pytest.raises(CampaignSpecError, match=match):
            parse_spec(base + bad, "s", scenario_data)


def test_the_report_draws_success_and_error_against_every_sampled_parameter(
    tmp_path, scenario_data
):
    """One sensitivity figure per sampled parameter (a panel per component that varies)."""
    from tdacm.campaign.report import sampled_values, write_report
    from tdacm.campaign.store import write_row

    spec = parse_spec(
        'scenario = "paper-in-fov"\nruns = 24\nseed = 3\n[distributions]\n'
        '"initial.q" = { kind = "normal", std = [0, 0, 0.02, 0.05, 0.05, 0.05, 0.02, 0.02] }\n'
        '"model.perturbation" = { kind = "uniform", low = 0.05, high = 0.15 }\n'
        '"cameras.local_renderer" = { kind = "choice", values = ["planar", "analytic"] }\n',
        "s",
        scenario_data,
    )
    store = tmp_path / "results"
    store.mkdir()
    rng = np.random.default_rng(0)
    for i, seed in enumerate(spec.run_seeds()):
        over = sample_overrides(spec, scenario_data, int(seed))
        final = float(over["model"]["perturbation"] * rng.uniform(0.05, 0.2))
        write_row(store, {"run": i, "seed": int(seed), "status": "ok", "success": final < 0.01,
                          "final_rmse": final, "overrides": json.dumps(over)})  # fmt: skip
    write_row(store, {"run": 24, "seed": 1, "status": "error", "success": False,
                      "error": "worker failure", "overrides": ""})  # fmt: skip
    report = write_report(spec, tmp_path)
    names = {"sensitivity/initial.q.png", "sensitivity/model.perturbation.png",
             "sensitivity/cameras.local_renderer.png"}  # fmt: skip
    assert set(report["sensitivity"]) == names
    for name in names:
        assert (tmp_path / name).stat().st_size > 10_000
    assert "sensitivity/model.perturbation.png" in (tmp_path / "report.md").read_text()
    cols = sampled_values(read_results(tmp_path), "initial.q")
    assert list(cols) == [f"initial.q[{i}]" for i in range(2, 8)]  # the components that vary
    assert np.isnan(cols["initial.q[2]"][-1])  # the failed run has no sampled value

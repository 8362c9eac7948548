"""A robustness sweep over camera noise (15-30 px) has no error rows, and the report's replay
command reproduces a stored row."""

import json
import shlex

import pytest

from tdacm.campaign import read_results, run_campaign
from tdacm.cli import main

SCENARIO = """
extends = "paper-in-fov"
name = "paper-in-fov-fast"
[cameras]
local_renderer = "analytic"
global_renderer = "planar"
global_every = 0
"""

# The block loop: `tdacm run` replays its rows bit for bit (a batched world draws its noise
# from its own stream; docs/campaigns.md).
SPEC = """
scenario = "fast.toml"
runs = 3
seed = 11
duration = 0.4
batched = false
[distributions]
"sensors.pixel_noise" = { kind = "truncnormal", mean = 22.0, std = 5.0, low = 15.0, high = 30.0 }
"""


def test_noise_sweep_has_no_error_rows_and_replays_reproduce_rows(tmp_path, capsys):
    (tmp_path / "fast.toml").write_text(SCENARIO)
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    out = tmp_path / "c"
    report = run_campaign(spec, out, workers=1, progress=False)
    df = read_results(out)
    assert len(df) == 3 and report["errors"] == 0, df["error"].tolist()
    assert (df["status"] == "ok").all()
    noise = [json.loads(o)["sensors"]["pixel_noise"] for o in df["overrides"]]
    assert all(15 <= x <= 30 for x in noise)
    worst = report["worst_runs"][0]
    cmd = shlex.split(worst["replay"])
    assert cmd[:2] == ["tdacm", "run"] and cmd[cmd.index("--duration") + 1] == "0.4"
    capsys.readouterr()
    code = main(["-q", *cmd[1:], "--out", str(tmp_path / "replay")])
    summary = json.loads(capsys.readouterr().out)
    row = df[df["run"] == worst["run"]].iloc[0]
    assert code == (1 if row["terminated"] else 0)
    assert summary["final_rmse"] == pytest.approx(row["final_rmse"], rel=0, abs=0)
    assert summary["duration"] == pytest.approx(0.4)
    assert (summary["termination"] or "") == row["termination"]

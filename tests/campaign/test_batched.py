"""Campaigns on the batched engine: rows equal to the block loop's without noise, the
fallback naming the key, chunks through Dask with resume, and (slow) the success rates of a
noisy campaign on both engines agreeing."""

import dataclasses
import math

import numpy as np
import pytest

from tdacm.campaign import CampaignSpecError, execute_run, parse_spec, read_results, run_campaign
from tdacm.campaign.batched import execute_chunk, refusal, shared_overrides
from tdacm.campaign.runner import use_batched
from tdacm.campaign.store import ROW_FIELDS, write_row
from tdacm.sim.scenario import load_scenario

ENGINE = """
"cameras.local_renderer" = { kind = "fixed", value = "analytic" }
"cameras.global_renderer" = { kind = "fixed", value = "planar" }
"ibvs.features" = { kind = "fixed", value = "measured" }
"""

SPEC = (
    """
scenario = "paper-in-fov"
runs = 8
seed = 3
duration = 1.5
success_rmse = 0.05
success_window = 0.5
[distributions]
"initial.q" = { kind = "normal", std = [0.0, 0.0, 0.05, 0.1, 0.1, 0.2, 0.05, 0.05] }
"model.perturbation" = { kind = "fixed", value = 0.1 }
"""
    + ENGINE
)


def _spec(text, scenario="paper-in-fov", **changes):
    spec = parse_spec(text, "spec.toml", load_scenario(scenario).data)
    return dataclasses.replace(spec, **changes)


def _same(a, b):
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or abs(a - b) <= 1e-9
    return a == b


OUT_OF_FOV = (
    """
scenario = "paper-out-of-fov"
runs = 3
seed = 5
duration = 1.5
[distributions]
"initial.q" = { kind = "normal", std = [0.0, 0.0, 0.05, 0.1, 0.1, 0.2, 0.05, 0.05] }
"safety.growth_limit" = { kind = "fixed", value = 0.0001 }
"safety.min_increase" = { kind = "fixed", value = 0.0 }
"safety.grace" = { kind = "fixed", value = 0.0 }
"""
    + ENGINE
)


#: runs that sample per-world parameters: the target's tilt, the rod's stiffness and density,
#: the drone's mass, the tendons' radius (noise off)
PER_WORLD = SPEC.replace("runs = 8", "runs = 4") + (
    """
"scene.target_tilt_deg" = { kind = "normal", std = [0.5, 0.5] }
"robot.rod.youngs_modulus" = { kind = "uniform", low = 4.5e10, high = 5.5e10 }
"robot.rod.density" = { kind = "uniform", low = 5800.0, high = 7100.0 }
"robot.drone.mass" = { kind = "uniform", low = 0.66, high = 0.81 }
"robot.tendons.radius" = { kind = "uniform", low = 0.009, high = 0.011 }
"""
)


#: on the EKF's estimates with noiseless, unbiased sensors (the engine's random streams are
#: not numpy's; without noise both run the same numbers): the estimation columns too
ON_ESTIMATES = SPEC.replace("runs = 8", "runs = 3") + "".join(
    f'"{key}" = {{ kind = "fixed", value = {value} }}\n'
    for key, value in [
        ("estimation.source", '"estimated"'), ("sensors.accel_bias", 0.0),
        ("sensors.accel_noise", 0.0), ("sensors.gyro_bias", 0.0), ("sensors.gyro_noise", 0.0),
        ("sensors.encoder_noise", 0.0), ("sensors.encoder_resolution", 0.0),
        ("sensors.pose_attitude_noise", 0.0), ("sensors.pose_position_noise", 0.0),
    ]
)  # fmt: skip


#: servoing into contact from 0.18 m above the standoff view (the touch, the settled force and
#: the 3 s hold within 18 s): the hold's figures and the force columns too
TOUCH = """
scenario = "touch-target"
runs = 2
seed = 4
duration = 18.0
success_rmse = 0.01
success_hold_force_rms = 0.2
[distributions]
"initial.q" = { kind = "fixed", value = [0.0, 0.0, 0.1, 0.1, -0.1, 2.0, 0.1, -0.1] }
"model.perturbation" = { kind = "fixed", value = 0.1 }
"cameras.local_renderer" = { kind = "fixed", value = "analytic" }
"cameras.global_renderer" = { kind = "fixed", value = "planar" }
"""


#: the two-arm squeeze from 1 cm above its contact pose with a 1 cm standoff, no model error
#: (both touches, the 3 s hold from about 7.5 s), the board tilted per run: each arm's marker
#: with the run's tilt, the per-arm force and task image error columns
SQUEEZE = """
scenario = "dual-squeeze"
runs = 2
seed = 6
duration = 11.0
success_rmse = 0.01
success_hold_force_rms = 0.2
[distributions]
"initial.q" = { kind = "fixed", value = [0.0, 0.0, 0.0, 0.0, 0.0, 2.0199, 0.4, 0.0, -0.4, 0.0] }
"model.perturbation" = { kind = "fixed", value = 0.0 }
"scene.target_tilt_deg" = { kind = "normal", std = [0.5, 0.5] }
"touch.standoff" = { kind = "fixed", value = 0.01 }
"touch.dwell" = { kind = "fixed", value = 0.1 }
"cameras.local_renderer" = { kind = "fixed", value = "analytic" }
"cameras.global_renderer" = { kind = "fixed", value = "planar" }
"""


@pytest.mark.parametrize(
    "text, scenario",
    [
        (SPEC, "paper-in-fov"),
        (OUT_OF_FOV, "paper-out-of-fov"),
        (PER_WORLD, "paper-in-fov"),
        (ON_ESTIMATES, "paper-in-fov"),
        (TOUCH, "touch-target"),
        (SQUEEZE, "dual-squeeze"),
    ],
    ids=[
        "in-fov",
        "recovery-then-safety-stop",
        "per-world-parameters",
        "on-estimates",
        "touch",
        "squeeze",
    ],  # fmt: skip
)
def test_noise_free_batched_rows_equal_the_block_loop_rows(text, scenario):
    """Runs with sampled initial states and seeded model errors (in-FoV: 8 runs to their
    end; out of FoV: the recovery, the switch to IBVS, then a hair-trigger safety monitor
    stopping each run): every stored field of each batched row, the termination's words
    included, equals the block loop's row of the same run to 1e-9 (wall times aside)."""
    spec = _spec(text, scenario=scenario)
    assert refusal(spec) is None
    seeds = [int(s) for s in spec.run_seeds()]
    d = dict(spec.__dict__)
    rows = execute_chunk(d, list(range(spec.runs)), seeds)
    assert [r["run"] for r in rows] == list(range(spec.runs))
    for b in rows:
        r = execute_run(d, b["run"], b["seed"])
        assert b["status"] == r["status"] == "ok", b["error"] + r["error"]
        for k in (*ROW_FIELDS, "success", "overrides"):
            if k != "wall_time_s":
                assert _same(b.get(k), r.get(k)), (b["run"], k, b.get(k), r.get(k))
    if "estimated" in text:
        assert all(np.isfinite(r["strain_estimation_rms"]) for r in rows)
    if scenario in ("touch-target", "dual-squeeze"):  # held, judged on the true force and
        # the task's view (the squeeze: every arm's)
        assert all(r["success"] and r["hold_force_rms_rel"] < 0.2 for r in rows)
    finals = [r["final_rmse"] for r in rows]
    assert len(set(np.round(finals, 9))) == spec.runs  # the runs differ (q0, model error)
    if scenario == "paper-out-of-fov":
        assert all(r["termination"] == "safety" and r["mode_switch_time"] > 0 for r in rows)


def test_auto_falls_back_naming_the_key_and_true_refuses(caplog):
    """A key the engine cannot vary per world, or a scenario it does not run: ``"auto"``
    runs the block loop with a notice naming it, ``true`` stops with that line."""
    varied = SPEC.replace(
        '"model.perturbation" = { kind = "fixed", value = 0.1 }',
        '"model.perturbation" = { kind = "uniform", low = 0.0, high = 0.1 }',
    )
    spec = _spec(varied)
    assert "model.perturbation" in refusal(spec)
    with caplog.at_level("INFO", logger="tdacm.campaign"):
        assert use_batched(spec) is False
    assert "not batched" in caplog.text and "model.perturbation" in caplog.text
    with pytest.raises(CampaignSpecError, match=r"batched = true: .*model\.perturbation"):
        use_batched(dataclasses.replace(spec, batched=True))
    rendered = _spec(SPEC.replace(ENGINE, ""), batched=True)
    with pytest.raises(CampaignSpecError, match="cameras.local_renderer"):
        use_batched(rendered)
    assert use_batched(_spec(SPEC, batched=False)) is False
    # a constant draw (fixed, a choice of one value) is shared, not per world
    one = _spec(SPEC + '"sensors.latency_steps" = { kind = "choice", values = [1] }\n')
    assert refusal(one) is None
    assert shared_overrides(one, load_scenario("paper-in-fov").data)["sensors"] == {
        "latency_steps": 1
    }


def test_batched_campaign_through_dask_resumes_with_the_same_rows(tmp_path):
    """A store holding runs 0-2 (run as one chunk here) resumed on a local Dask worker: the
    stored rows are kept, runs 3-5 run in chunks, and each row equals the same run in a
    chunk of its own (a row does not depend on its chunk). One cluster start (~15 s)."""
    spec = _spec(SPEC, runs=6, duration=0.3, batched=True)
    out = tmp_path / "c"
    (out / "results").mkdir(parents=True)
    seeds = [int(s) for s in spec.run_seeds()]
    d = dict(spec.__dict__)
    first = execute_chunk(d, [0, 1, 2], seeds[:3])
    for row in first:
        row["error"] = "kept"  # marks the stored rows: a resume does not redo them
        write_row(out / "results", row)
    report = run_campaign(spec, out, workers=1, progress=False)
    assert report["complete"]
    df = read_results(out)
    assert list(df["run"]) == list(range(6)) and (df["status"] == "ok").all()
    assert list(df["error"]) == ["kept"] * 3 + [""] * 3
    for i in (1, 4):
        alone = execute_chunk(d, [i], [seeds[i]])[0]
        for k in ("final_rmse", "late_rmse_1s", "max_tension", "time_to_0.01", "overrides"):
            want = float("nan") if alone[k] is None else alone[k]  # the store: None -> NaN
            assert _same(df.loc[i, k], want), (i, k)


def _two_proportion_p(k1, n1, k2, n2) -> float:
    """Two-sided p-value of the pooled two-proportion z-test."""
    p = (k1 + k2) / (n1 + n2)
    se = math.sqrt(p * (1 - p) * (1 / n1 + 1 / n2))
    if se == 0:
        return 1.0
    z = (k1 / n1 - k2 / n2) / se
    return math.erfc(abs(z) / math.sqrt(2))


@pytest.mark.slow
def test_noisy_success_rates_agree_between_the_engines(tmp_path):
    """200 runs each with 0.3 px of corner noise and 5 % dropped frames (different random
    streams on the two engines), judged on the RMS of the last second at 0.2 (the measured-
    feature servo is still converging at 3 s; the safety monitor stops about a third of the
    runs on noise, so the rate lies away from 0 and 1): the success rates pass a
    two-proportion test at 95 %."""
    text = SPEC.replace("runs = 8", "runs = 200").replace("duration = 1.5", "duration = 3.0")
    text = text.replace("success_rmse = 0.05", "success_rmse = 0.2")
    text = text.replace("success_window = 0.5", "success_window = 1.0")
    text += '"sensors.pixel_noise" = { kind = "fixed", value = 0.3 }\n'
    text += '"sensors.dropout" = { kind = "fixed", value = 0.05 }\n'
    rates = {}
    for batched in (True, False):
        out = tmp_path / str(batched)
        run_campaign(_spec(text, batched=batched), out, workers=2, progress=False)
        df = read_results(out)
        assert len(df) == 200 and (df["status"] == "ok").all()
        rates[batched] = int(df["success"].sum())
    assert 20 <= rates[False] <= 180, rates  # a rate away from 0 and 1: the test can fail
    assert _two_proportion_p(rates[True], 200, rates[False], 200) > 0.05, rates
    print(f"success: batched {rates[True]}/200, block loop {rates[False]}/200")

"""Smoke tests of the benchmark studies (tiny sizes; the real runs are ``run_full_bench``)."""

import json

import numpy as np

from tdacm.baselines import study


def test_scaling_rows():
    rows = study.scaling_study(orders=[0, 1], gauss=[4], repeats=1, number=2)
    assert [r["n_s"] for r in rows] == [2, 4]
    assert all(r["fd_kernel_us"] > 0 and r["fd_api_us"] > 0 for r in rows)
    json.dumps(rows)


def test_closed_loop_runs_on_both_models(gvs_floating, cc_floating):
    for model in (gvs_floating, cc_floating):
        times, q = study.closed_loop(model, gvs_floating, duration=0.06)
        assert times.shape == (3,) and np.all(times > 0)
        assert np.all(np.isfinite(q))


def test_pyelastica_section_is_reported():
    """Skipped-with-a-reason without the optional extra; a short stable run with it."""
    out = study.pyelastica_study(duration=0.01)
    assert isinstance(out, dict) and out
    if "skipped" not in out:
        assert out["finite"] and len(out["tip"]) == 2


def test_plots(tmp_path):
    rows = study.scaling_study(orders=[0], gauss=[4], repeats=1, number=2)
    study.plot_scaling(rows, tmp_path / "s.png", cc_fd_s=5e-4)
    err = [0.0, 1e-3, 2e-3]
    acc = {
        "duration_s": 0.02,
        "rk4_dt_s": 0.01,
        "cases": {
            "c": {
                "description": "d",
                "t": [0.0, 0.01, 0.02],
                "reference_self_error_m": 1e-4,
                "reference_tip_travel_m": 0.1,
                "models": {
                    name: {
                        "n_s": 2,
                        "fd_us": 1.0,
                        "max_error_m": 2e-3,
                        "rms_error_m": 1e-3,
                        "final_error_m": 2e-3,
                        "error_m": err,
                    }
                    for name in ("CC", "GVS-0")
                },
            }
        },
    }
    study.plot_accuracy(acc, tmp_path / "a.png")
    assert (tmp_path / "s.png").stat().st_size > 0 and (tmp_path / "a.png").stat().st_size > 0

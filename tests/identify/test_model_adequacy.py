"""Model adequacy of an identification: the misfit diagnosis, the strain basis chosen from the
data, the sandwich covariance and the stiff shooting step (docs/identify.md, sections 7-8).
Small synthetic recordings: seconds each."""

from __future__ import annotations

import json
import tomllib
from types import SimpleNamespace

import numpy as np
import pytest

from tdacm.cli import main
from tdacm.identify import synthesize
from tdacm.identify.experiments import PRIOR_DAMPING
from tdacm.identify.fit import sandwich_covariance
from tdacm.identify.misfit import EXIT_MISFIT
from tdacm.identify.solve import Blocks

#: A hidden robot with the scenario's nominal values but E and a richer basis: fitting E
#: alone is then exact on the right basis.
TRUTH = {"E": 4.3e10, "damping": PRIOR_DAMPING, "tip_mass": 0.01, "radius": 0.01}


def _fake_problem(nt):
    rec = SimpleNamespace(t=np.arange(nt))
    s = SimpleNamespace(rec=rec, kdim=1, starts=np.array([0]), ends=np.array([nt]))
    return SimpleNamespace(setups=[s], blocks=Blocks(1, [(0, nt)], [(1, 1)]))


def test_sandwich_covariance_is_the_long_run_variance_of_correlated_residuals():
    # the estimate of a mean (J = ones) from AR(1) residuals: var = (1 + rho) / (1 - rho) / T
    # times the innovation-scaled variance; the white-noise formula misses that factor
    rng = np.random.default_rng(12)
    nt, rho = 20000, 0.8
    e = rng.standard_normal(nt) * np.sqrt(1 - rho**2)
    r = np.empty(nt)
    r[0] = rng.standard_normal()
    for t in range(1, nt):
        r[t] = rho * r[t - 1] + e[t]
    jac = np.ones((nt, 1))
    cov, lags = sandwich_covariance(_fake_problem(nt), jac, r, 1)
    want = (1 + rho) / (1 - rho) / nt
    assert cov[0, 0] == pytest.approx(want, rel=0.25)  # HAC's own sampling error ~10 %
    assert lags > 5
    white, _ = sandwich_covariance(_fake_problem(nt), jac, e / np.sqrt(1 - rho**2), 1)
    assert white[0, 0] == pytest.approx(1 / nt, rel=0.15)


def test_stiff_bases_shoot_with_the_l_stable_step():
    # bending:2 at the nominal damping: |lambda| dt = 2.3 at 20 ms (beyond RK4_LIMIT, near RK4's
    # stability edge); the ROS34PW2 step at 20 ms follows RK4 at 2.5 ms
    rec = synthesize("tendon-steps", seed=1, duration=3.0, basis="bending:2", truth=TRUTH)
    rec = rec.with_basis("bending:2").decimated(2)
    model = rec.model
    assert model.fastest_rate() * rec.dt > 1.5
    n = model.system.n
    nt = len(rec.t)
    z = np.zeros((1, n))
    fine = model.simulate(TRUTH, z, z, [0], [nt], rec.u, rec.dt, 8)
    coarse = model.simulate(TRUTH, z, z, [0], [nt], rec.u, rec.dt, 1)
    assert coarse.ok and fine.ok
    err = np.abs(coarse.tip[:, :3, 3] - fine.tip[:, :3, 3]).max()
    assert err < 1e-4, err  # a fifth of the motion capture's noise


def test_cli_flags_a_poor_basis_and_strict_exits_3(tmp_path, capsys):
    synthesize("tendon-steps", seed=21, duration=4.0, basis="bending:1", truth=TRUTH,
               noise={"tension": 0.0}, out=tmp_path / "rec")  # fmt: skip
    base = ["identify", str(tmp_path / "rec"), "--params", "E", "--decimate", "2"]
    out = tmp_path / "paper"
    # the scenario's basis (bending:0) alone: flagged, and --strict makes it an exit code
    assert main([*base, "--out", str(out), "--strict"]) == EXIT_MISFIT
    err = capsys.readouterr().err
    assert "MISFIT" in err and "--bases" in err
    report = json.loads((out / "identification.json").read_text())
    assert report["misfit"]["detected"] and report["misfit"]["variance_ratio"] > 10
    assert "WARNING: misfit" in (out / "robot.toml").read_text()
    assert main([*base, "--bases", "bending:x"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith("error: --bases")


@pytest.mark.slow
def test_cli_chooses_the_basis_on_held_out_data(tmp_path, capsys):
    """Three fits of a few seconds each, a minute on a busy machine."""
    synthesize("tendon-steps", seed=21, duration=5.0, basis="bending:1", truth=TRUTH,
               noise={"tension": 0.0}, out=tmp_path / "rec")  # fmt: skip
    synthesize("held-out", seed=21, duration=3.0, basis="bending:1", truth=TRUTH,
               noise={"tension": 0.0}, out=tmp_path / "held")  # fmt: skip
    base = ["identify", str(tmp_path / "rec"), "--params", "E", "--decimate", "2"]
    # the two bases compared on the held-out recording: bending:1 chosen, bending:0 flagged
    out = tmp_path / "select"
    code = main([*base, "--out", str(out), "--strict", "--bases", "bending:0,bending:1",
                 "--held-out", str(tmp_path / "held")])  # fmt: skip
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "inadequate bases (misfit beyond the noise): bending:0" in cap.err
    report = json.loads((out / "identification.json").read_text())
    rows = {r["basis"]: r for r in report["basis_selection"]}
    assert rows["bending:1"]["chosen"] and rows["bending:0"]["misfit"]
    assert rows["bending:1"]["bic"] < rows["bending:0"]["bic"]
    assert not report["misfit"]["detected"]
    assert report["misfit"]["variance_ratio"] < 1.5
    block = tomllib.loads((out / "robot.toml").read_text())
    assert block["robot"]["rod"]["basis"] == "bending:1"
    assert block["robot"]["rod"]["youngs_modulus"] == pytest.approx(TRUTH["E"], rel=2e-3)

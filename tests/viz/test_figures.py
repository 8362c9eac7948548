"""Figures of a run: units, legends with the mode switch, the paper's panels, and `tdacm plot`."""

import numpy as np
import pytest

from tdacm.sim import load_scenario
from tdacm.viz.figures import RunData, fig_state_errors, plot_run


def _synthetic(T=60, switch=20):
    t = np.arange(T) * 0.02
    q = np.zeros((T, 8))
    q[:, 5] = 3.0 + 0.5 * np.exp(-t)
    q[:, 6] = 0.2 * np.exp(-t)
    mode = np.where(np.arange(T) < switch, 1, 0)
    return {
        "t": t, "q": q, "qd": np.gradient(q, axis=0) / 0.02, "q_d": q * 0.9, "qd_d": q * 0,
        "q_ref": q, "u": np.ones((T, 8)), "features": np.zeros((T, 6)),
        "feature_error": np.exp(-t)[:, None] * np.ones(6), "twist": np.ones((T, 6)),
        "points_virtual": np.full((T, 4, 2), 0.1), "points_local": np.full((T, 4, 2), 0.1),
        "rmse": 0.3 * np.exp(-t), "mode": mode, "V": np.exp(-t),
        "brand_new_key": np.zeros((T, 3)),  # extra keys are ignored
    }  # fmt: skip


def test_state_errors_are_to_the_desired_configuration_with_switch_in_legend(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = _synthetic()
    rd = RunData(a, {"scenario": "x"}, True, q_star=np.r_[np.zeros(5), 3.0, 0, 0])
    captured = {}
    orig = plt.close
    plt.close = lambda fig=None: captured.setdefault("fig", fig)
    try:
        paths = fig_state_errors(rd, tmp_path, ("png",))
    finally:
        plt.close = orig
    fig = captured["fig"]
    axes = fig.axes
    assert [p.name for p in paths] == ["state_errors.png"]
    assert [ax.get_ylabel() for ax in axes] == [
        "error angle (deg)", "error position (m)", "error strain (1/m)"]  # fmt: skip
    z = [ln for ln in axes[1].lines if ln.get_label() == "$z$"][0]
    assert z.get_ydata()[0] == pytest.approx(0.5)  # z - 3 m, not q - q_d
    for ax in axes:
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        assert "switch to IBVS" in labels and "recovery (C_G plan)" in labels
    plt.close(fig)


def test_every_kind_tolerates_missing_and_extra_keys(tmp_path):
    a = _synthetic()
    for k in ("twist", "qd_d", "V"):
        a.pop(k)
    paths = plot_run(tmp_path, a, {"scenario": "x"}, np.full((4, 2), 0.1),
                     scenario=load_scenario("paper-in-fov"), formats=("png",))  # fmt: skip
    names = {p.stem for p in paths}
    assert "camera_twist" not in names and "lyapunov" not in names
    assert {"state_errors", "tracking_errors", "actuation", "features", "feature_error",
            "strain_rates", "snapshots"} <= names  # fmt: skip

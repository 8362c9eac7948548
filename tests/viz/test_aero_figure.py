"""The wake figure of docs/aerodynamics.md is drawn from the model."""

import matplotlib

matplotlib.use("Agg")

import pytest  # noqa: E402

from tdacm.viz.aero import wake_figure  # noqa: E402


def test_wake_figure_is_written(tmp_path):
    path = tmp_path / "wake.png"
    fig = wake_figure(path, grid=21)
    assert path.stat().st_size > 10_000
    hanging, bent = (ax.get_title() for ax in fig.axes[:2])
    # the straight hanging rod in the vertical wake feels skin friction only (0.02 mN); bent
    # across rotor 0's jet, millinewtons
    assert "rod 0.02 mN" in hanging and "rod 3.8 mN" in bent


def test_wake_figure_needs_a_drone():
    import tdacm
    from tdacm.base import FixedBase

    s = tdacm.paper_system()
    held = tdacm.TDACM(s.arms[0].rod, s.arms[0].tendons, FixedBase(), s.arms[0].attachment)
    with pytest.raises(ValueError, match="floating"):
        wake_figure(None, system=held)

"""Wind: steady, 1-cosine gust, Dryden turbulence against its analytic spectra."""

import math

import numpy as np
import pytest
from scipy.signal import welch

from tdacm.aero import DrydenTurbulence, Gust, SteadyWind
from tdacm.aero.wind import FT, dryden_psd, low_altitude_scales


def test_steady_wind_and_gust():
    w = SteadyWind([2.0, -1.0, 0.0]) + Gust([0.0, 3.0, 0.0], start=1.0, duration=2.0)
    assert w.velocity(0.5) == pytest.approx([2.0, -1.0, 0.0])
    assert w.velocity(2.0) == pytest.approx([2.0, 2.0, 0.0])  # the gust's peak, mid-way
    assert w.velocity(1.5) == pytest.approx([2.0, 0.5, 0.0])  # 3/2 (1 - cos(pi/2))
    assert w.velocity(3.5, p=[1, 2, 3]) == pytest.approx([2.0, -1.0, 0.0])
    with pytest.raises(ValueError, match="duration"):
        Gust([1, 0, 0], 0.0, 0.0)


def test_low_altitude_scales_match_the_specification():
    # at 1000 ft the low-altitude form joins the isotropic one: L_u = L_v = L_w, equal sigmas
    sig, lengths = low_altitude_scales(999.999 * FT, 10.0)
    assert sig == pytest.approx([1.0, 1.0, 1.0], rel=1e-5)
    assert lengths == pytest.approx(np.full(3, 999.999 * FT), rel=1e-5)
    sig, lengths = low_altitude_scales(3.0, 5.0)  # 9.8 ft: the spec's 10 ft floor
    c = 0.177 + 0.000823 * 10.0
    assert sig == pytest.approx([0.5 / c**0.4, 0.5 / c**0.4, 0.5])
    assert lengths == pytest.approx(np.array([10 / c**1.2, 10 / c**1.2, 10.0]) * FT)


def test_dryden_spectra_match_the_analytic_psd():
    """Welch estimate of 2^18 samples (fs = 50 Hz, 4096-sample Hann segments, 50 % overlap:
    127 segments) against ``2 pi Phi(2 pi f)``, averaged over bands of 16 bins from 0.05 to
    2 Hz.  The relative standard deviation of a band is about ``1 / sqrt(127 x 16 / 2) = 3 %``
    (adjacent Hann bins are correlated), so 12 % is four of them; the window's leakage at 0.05 Hz
    (above the u corner, 0.04 Hz, by 4 bins) and aliasing (below 0.2 % at 2 Hz) are smaller."""
    sigma = np.array([1.0, 1.2, 0.5])
    scale = np.array([20.0, 20.0, 5.0])
    v, fs = 5.0, 50.0
    turb = DrydenTurbulence(sigma, scale, airspeed=v, dt=1 / fs, seed=3)
    x = turb.sample(2**18)
    assert np.var(x, axis=0) == pytest.approx(sigma**2, rel=0.15)
    f, p = welch(x, fs=fs, nperseg=4096, axis=0)
    sel = (f >= 0.05) & (f <= 2.0)
    idx = np.nonzero(sel)[0]
    for i in range(3):
        model = 2 * math.pi * dryden_psd(2 * math.pi * f, sigma[i], scale[i], v, i == 0)
        for b in range(0, idx.size - 15, 16):
            band = idx[b : b + 16]
            assert p[band, i].mean() == pytest.approx(model[band].mean(), rel=0.12)


def test_dryden_psd_integrates_to_variance():
    om = np.linspace(0, 2000, 2_000_001)
    for lon in (True, False):
        psd = dryden_psd(om, 1.5, 10.0, 4.0, lon)
        assert np.trapezoid(psd, om) == pytest.approx(2.25, rel=2e-3)


def test_dryden_is_seeded_and_moves_forward():
    a = DrydenTurbulence([1, 1, 1], [10, 10, 3], 3.0, dt=0.01, seed=5, direction=(0.0, 1.0))
    b = DrydenTurbulence([1, 1, 1], [10, 10, 3], 3.0, dt=0.01, seed=5, direction=(0.0, 1.0))
    va = [a.velocity(t) for t in np.arange(0, 1, 0.02)]
    vb = [b.velocity(t) for t in np.arange(0, 1, 0.02)]
    assert np.array_equal(va, vb)
    with pytest.raises(ValueError, match="forward in time"):
        a.velocity(0.1)
    a.reset()
    assert np.array_equal(a.velocity(0.0), vb[0])

"""Strains from tendon lengths (least squares) - the estimator's initialization."""

import numpy as np
import pytest

from tdacm import paper_system
from tdacm.estimation import strains_from_tendon_lengths
from tdacm.rod import StrainBasis
from tdacm.system.tdacm import TDACM, default_attachment


@pytest.mark.parametrize("qs", [[0.0, 0.0], [0.3, -0.4], [-1.2, 0.9], [2.5, 2.0]])
def test_exact_inversion_paper_system(qs):
    s = paper_system()
    q = np.concatenate([np.zeros(6), qs])
    dl = s.tendon_lengths(q) - s.tendon_lengths(np.zeros(8))
    res = strains_from_tendon_lengths(s, dl, q0=[0.5, 0.5])
    assert res.success and res.rank == 2
    np.testing.assert_allclose(res.q_s, qs, atol=1e-10)
    assert np.max(np.abs(res.residual)) < 1e-13


def test_inversion_relative_to_a_bent_zeroing_configuration():
    s = paper_system()
    q_ref = np.array([0.2, 0.1])
    q = np.concatenate([np.zeros(6), [-0.5, 0.4]])
    dl = s.tendon_lengths(q) - s.tendon_lengths(np.concatenate([np.zeros(6), q_ref]))
    res = strains_from_tendon_lengths(s, dl, q_ref=q_ref)
    np.testing.assert_allclose(res.q_s, [-0.5, 0.4], atol=1e-10)


def test_inversion_with_a_richer_basis_is_least_squares():
    """A linear-in-s bending basis (4 strains) seen by 4 tendons: the length change only sees
    the mean curvature, so the inversion is rank deficient (reported, success False)."""
    p = paper_system()
    rod = p.rod.__class__(length=1.0, diameter=2e-3, basis=StrainBasis.bending(1))
    s = TDACM(rod, p.tendons, p.base, default_attachment())
    q = np.concatenate([np.zeros(6), [0.3, -0.2, 0.1, 0.05]])
    dl = s.tendon_lengths(q) - s.tendon_lengths(np.zeros(s.n))
    res = strains_from_tendon_lengths(s, dl)
    assert res.rank < s.n_s and not res.success
    assert np.max(np.abs(res.residual)) < 1e-10  # still matches the measured lengths


def test_noisy_quantized_lengths_give_millradian_strains():
    s = paper_system()
    rng = np.random.default_rng(0)
    q = np.concatenate([np.zeros(6), [0.3, -0.4]])
    dl = s.tendon_lengths(q) - s.tendon_lengths(np.zeros(8))
    errs = []
    for _ in range(200):
        z = np.round((dl + 5e-6 * rng.standard_normal(4)) / 1e-5) * 1e-5
        errs.append(strains_from_tendon_lengths(s, z).q_s - q[6:])
    # L r = 0.01 m per rad/m and two tendons per strain: std ~ sqrt(5e-6^2 + 1e-5^2/12)/0.01/sqrt(2)
    expected = np.sqrt(5e-6**2 + 1e-10 / 12) / 0.01 / np.sqrt(2)
    np.testing.assert_allclose(np.std(errs, axis=0), expected, rtol=0.15)


def test_bad_input_named():
    s = paper_system()
    with pytest.raises(ValueError, match="delta_lengths"):
        strains_from_tendon_lengths(s, [0.0, 0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="q_ref"):
        strains_from_tendon_lengths(s, np.zeros(4), q_ref=[0.0])

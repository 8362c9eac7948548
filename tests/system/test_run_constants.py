"""The run constants of the model arrays (:func:`tdacm.system.forward.run_constants`): what the
forward recursion takes from the model only is computed once, with the arithmetic the
recursion performed per evaluation, so ``qdd`` does not change by a bit:

* the sums over the basis blocks, ``K`` and ``D`` that skip their exact zeros give the dense
  sums' numbers;
* an order-4 Magnus step whose two samples are equal (an order-0 basis) taken as one sample
  gives the two-sample step's numbers (Zanna's commutators are exact zeros there), and the
  paper system then has the same ``qdd`` with Magnus order 2 and 4."""

from __future__ import annotations

import numpy as np
import pytest

import tdacm
from tdacm.rod import StrainBasis
from tdacm.system import kernels as K

from .conftest import random_state_and_input

SEEDS = range(4100, 4104)


def _dense(m):
    """``m`` with every sum over all columns and rows (the zeros included)."""
    ns, _, w = m.step_nzc.shape
    ng = m.g_nzc.shape[0]
    n = m.stiffness.shape[0]
    cols = lambda k: np.ascontiguousarray(np.broadcast_to(np.arange(w), (k, 6, w)))  # noqa: E731
    return m._replace(
        step_nzc=cols(ns),
        step_nzn=np.full((ns, 6), w, np.int64),
        g_nzc=cols(ng),
        g_nzn=np.full((ng, 6), w, np.int64),
        g_nzr=np.ascontiguousarray(np.broadcast_to(np.arange(6), (ng, w, 6))),
        g_nzrn=np.full((ng, w), 6, np.int64),
        kd_lo=np.zeros(n, np.int64),
        kd_hi=np.full(n, n, np.int64),
    )


def _qdd(q, qd, u, m, loads):
    qdd, ok = K.forward_dynamics(q, qd, u, m, loads)
    assert ok
    return qdd


@pytest.mark.parametrize(
    "basis, order", [(None, 2), (None, 4), (StrainBasis((3, 3, 3, None, None, None)), 4)]
)
def test_sparse_sums_give_the_dense_sums_numbers(basis, order):
    s = tdacm.paper_system(basis=basis, magnus_order=order, n_gauss=5)
    m, loads = s.model_arrays, s.loads.packed()
    assert np.any(m.step_nzn < m.step_nzc.shape[2])  # the blocks have zeros to skip
    dense = _dense(m)
    for seed in SEEDS:
        q, qd, u = random_state_and_input(s, seed, lift=False)
        assert np.array_equal(_qdd(q, qd, u, m, loads), _qdd(q, qd, u, dense, loads))
        ls = q[s.n - s.n_s :]
        a = K.tendon_lengths_and_matrix(ls, m)
        b = K.tendon_lengths_and_matrix(ls, dense)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_an_order_4_step_with_equal_samples_is_the_one_sample_step():
    s4 = tdacm.paper_system(magnus_order=4)  # the order-0 basis: equal samples
    s2 = tdacm.paper_system()
    m4, m2, loads = s4.model_arrays, s2.model_arrays, s4.loads.packed()
    assert m4.xi0s.shape[1] == 2 and np.all(m4.step_one == 1)
    assert np.all(m4.step_c4 > 0)
    two = m4._replace(step_one=np.zeros_like(m4.step_one))  # Zanna's two-sample arithmetic
    rich = tdacm.paper_system(basis=StrainBasis((3, 3, 3, None, None, None)), magnus_order=4)
    assert not np.any(rich.model_arrays.step_one)  # a varying basis keeps both samples
    for seed in SEEDS:
        q, qd, u = random_state_and_input(s4, seed, lift=False)
        a = _qdd(q, qd, u, m4, loads)
        assert np.array_equal(a, _qdd(q, qd, u, two, loads))
        assert np.array_equal(a, _qdd(q, qd, u, m2, loads))


def test_the_run_constants_are_the_steps_arithmetic():
    s = tdacm.paper_system(basis=StrainBasis((3, 3, 3, None, None, None)), magnus_order=4)
    m = s.model_arrays
    h = m.h[:, None, None]
    assert np.array_equal(m.step_z, 0.5 * h * (m.bs[:, 0] + m.bs[:, 1]))
    assert np.array_equal(m.step_c4, np.sqrt(3.0) / 12.0 * m.h * m.h)
    off = s.n - s.n_s
    # K and D are zero outside the strain blocks: the drone's rows are empty
    assert np.all(m.kd_hi[:off] == 0) and np.all(m.kd_lo[off:] >= off)
    for i in range(s.n):
        row = np.abs(m.stiffness[i]) + np.abs(m.damping[i])
        assert not np.any(row[: m.kd_lo[i]]) and not np.any(row[m.kd_hi[i] :])

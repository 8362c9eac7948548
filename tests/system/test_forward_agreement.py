"""The forward-dynamics recursion (:mod:`tdacm.system.forward`) against the full recursion
with ``C`` and ``J_dot`` (:func:`tdacm.system.kernels.coupled_terms_env` with ``want_c = True``,
:func:`tdacm.system.kernels.rod_step`): two implementations of paper eqs. (9)-(11), (16) that
share no loop.  On random states (seeds held out from ``test_kernel_reference.py``) of the
paper system and the 18-DoF rod, ``M``, ``C qdot``, ``tau_ext``, the tip pose and ``J`` agree
to 1e-12 of each array's largest entry, and ``qdd`` solves ``M qdd = B u + tau_ext - C qdot -
D qdot - K q`` formed from the full recursion's ``M``, ``C`` and the dense ``B(q)`` with a
normwise backward error below 1e-12."""

from __future__ import annotations

import numpy as np
import pytest

import tdacm
from tdacm.rod import StrainBasis
from tdacm.system import kernels as K

from .conftest import random_state_and_input

TOL = 1e-12
SEEDS = range(2000, 2005)


@pytest.fixture(scope="module", params=["paper", "rich"])
def system(request):
    if request.param == "paper":
        return tdacm.paper_system()
    return tdacm.paper_system(
        basis=StrainBasis((3, 3, 3, None, None, None)), n_gauss=8, magnus_order=4
    )


def _close(a, b):
    scale = max(1.0, float(np.abs(b).max()))
    return float(np.abs(a - b).max()) <= TOL * scale


@pytest.mark.parametrize("seed", SEEDS)
def test_the_forward_recursion_agrees_with_the_full_one(system, seed):
    m, loads, e = system.model_arrays, system.loads.packed(), np.empty(0)
    q, qd, u = random_state_and_input(system, seed)
    fast = K.coupled_terms_env(q, qd, m, loads, False, u, e, e)
    full = K.coupled_terms_env(q, qd, m, loads, True, u, e, e)
    for i, name in ((0, "M"), (2, "C qdot"), (3, "tau"), (4, "tip pose"), (5, "J")):
        assert fast[i].shape == full[i].shape, name
        assert _close(fast[i], full[i]), name
    c_qd = full[1] @ qd
    assert _close(full[2], c_qd)  # C qdot of the recursion is the matrix C times qdot
    rhs = K.input_matrix(q, m) @ u + full[3] - c_qd - m.damping @ qd - m.stiffness @ q
    qdd, ok = K.forward_dynamics(q, qd, u, m, loads)
    assert ok
    # qdd solves the full recursion's system: its normwise backward error (the residual over
    # |M| |qdd| + |rhs|, infinity norms) is at rounding level.  Not qdd against another solve:
    # the two differ by rounding times the condition number of M (on the 18-DoF rod, M times
    # their difference reaches 3e-12 of |rhs|)
    res = float(np.abs(full[0] @ qdd - rhs).max())
    size = np.abs(full[0]).sum(axis=1).max() * np.abs(qdd).max() + np.abs(rhs).max()
    assert res <= TOL * size

import numpy as np
import pytest

import tdacm


@pytest.fixture(scope="session")
def paper():
    return tdacm.paper_system()


@pytest.fixture(scope="session")
def rich():
    """A floating rod with every strain mode (order 2, Zanna Magnus): n = 6 + 18."""
    return tdacm.paper_system(basis=tdacm.StrainBasis.full(2), magnus_order=4, n_gauss=8)


def random_state(system, seed=0, scale=0.5):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=system.n) * scale
    qd = rng.normal(size=system.n)
    if system.floating:
        q[3:6] += [0.2, -0.1, 3.0]
    return q, qd


def random_state_and_input(system, seed, lift=True):
    """``(q, qd, u)`` drawn from ``seed``: strains and drone angles at 0.4 (the angles halved),
    velocities at 1, inputs ``|N(0, 2)|``; ``lift`` moves the drone to ``[0.2, -0.1, 3.0]``
    from its draw."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=system.n) * 0.4
    qd = rng.normal(size=system.n)
    u = np.abs(rng.normal(size=system.n_u)) * 2.0
    q[0:3] *= 0.5
    if lift:
        q[3:6] += [0.2, -0.1, 3.0]
    return q, qd, u


def horizontal_cantilever(basis, **rod_kwargs):
    """A clamped rod along inertial +x (no attachment rotation), no tip mass."""
    defaults = dict(length=1.0, diameter=2e-3, damping=0.0, n_gauss=12, magnus_order=4)
    defaults.update(rod_kwargs)
    rod = tdacm.Rod(basis=basis, **defaults)
    return tdacm.TDACM(rod, tdacm.Tendons.parallel(0.01), tdacm.FixedBase(), attachment=np.eye(4))

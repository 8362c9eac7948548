"""The plant with the aerodynamics: wind through the packed array, identical without it."""

import numpy as np
import pytest

import tdacm
from tdacm.aero import Aerodynamics, SteadyWind
from tdacm.loop.plant import Plant
from tdacm.system import kernels as K
from tdacm.system.aero import aero_array


@pytest.fixture(scope="module")
def paper():
    return tdacm.paper_system()


def _start(s):
    q0 = np.zeros(s.n)
    q0[5] = 3.0
    u = np.r_[np.full(4, 9.81 * s.total_mass / 4), np.zeros(s.n_a)]
    return q0, np.zeros(s.n), u


def test_plant_without_aero_is_the_plain_kernel(paper):
    q0, qd0, u = _start(paper)
    p = Plant(paper, q0, qd0)
    st = p.advance(u, 0.02)
    qs, qds, _ = K.rk4_run(q0, qd0, u, 0.005, 4, 4, paper.model_arrays, paper.loads.packed())
    assert np.array_equal(st.q, qs[-1]) and np.array_equal(st.qd, qds[-1])


def test_wind_carries_the_drone_and_swings_the_arm(paper):
    q0, qd0, u = _start(paper)
    a = aero_array(paper, Aerodynamics())
    p = Plant(paper, q0, qd0, aero=a, wind=SteadyWind([5.0, 0.0, 0.0]))
    calm = Plant(paper, q0, qd0, aero=a.copy())
    for _ in range(25):
        st = p.advance(u, 0.02)
        st0 = calm.advance(u, 0.02)
    assert p.ok and calm.ok
    assert st.qd[3] > 0.05 and abs(st0.qd[3]) < 1e-9  # carried downwind, calm stays
    tip = paper.tip_pose(st.q)[:3, 3] - st.q[3:6]
    tip0 = paper.tip_pose(st0.q)[:3, 3] - st0.q[3:6]
    # the drone's drag per mass (1.7 N / 0.73 kg) exceeds the arm's (45 mN / 30 g): the drone is
    # carried away faster and the arm trails upwind of it; in calm air it stays below
    assert tip[0] < -0.01 and abs(tip0[0]) < 1e-9
    with pytest.raises(ValueError, match="wind needs aero"):
        Plant(paper, q0, qd0, wind=SteadyWind())
    other = tdacm.paper_system(n_gauss=8)
    with pytest.raises(ValueError, match="packed array of this system"):
        Plant(paper, q0, qd0, aero=aero_array(other))

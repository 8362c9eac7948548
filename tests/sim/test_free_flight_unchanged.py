"""Servoing into contact leaves the free flight alone: the paper's five scenarios give these
values to the last bit (0.1 s of each, six periods: the reference snapshot, the first views,
the controller's first commands and the plant's integration), on the project's platform
(numba and numpy as in its venv). Any change in those paths, the touch servo's task view and
its reference snapshot in C_L included (docs/contact.md), changes them."""

import math

import pytest

from tdacm.sim import Simulation, load_scenario

#: scenario -> (q at 0.1 s, u at 0.1 s, the normalized RMSE of every period, None for NaN)
BEFORE = {
    "paper-in-fov": (
        [
            0.014834922695644749,
            0.010261377392315685,
            0.1742706204929435,
            -0.4997119295944979,
            0.49969892884639955,
            4.999538015849498,
            -0.3123912385480815,
            -0.41634015109677514,
        ],
        [
            1.5363496508645094,
            1.8802213000556467,
            1.675705047092868,
            1.6985049333430773,
            0.0,
            0.9803150839853845,
            1.2191950106699205,
            0.019684916149266384,
        ],
        [
            0.39197556451854065,
            0.3919833248951798,
            0.3949359844463119,
            0.40214444888000894,
            0.410777949585923,
            0.41887554732969173,
        ],
    ),
    "paper-out-of-fov": (
        [
            0.0004407028076269945,
            0.0001587840009506509,
            -2.4877793817443523e-05,
            -8.522340746031047e-06,
            1.4191245570961583e-05,
            5.001284789544811,
            0.2984905729856313,
            0.3967232433545954,
        ],
        [
            1.8686273612271642,
            1.9439386569400532,
            1.9335063908418952,
            1.8577750735403247,
            3.339458459565077,
            0.0,
            0.0,
            2.499825256266858,
        ],
        [None, None, None, None, None, None],
    ),
    "ground-test-a": (
        [-0.10002633523497007, 0.10016073483920387],
        [0.9095927942580765, 0.910171947463073, 0.09040720585843949, 0.08982805255099115],
        [
            0.7723886482000397,
            0.7724546042750052,
            0.7725947058386472,
            0.7727121486139574,
            0.7727400694208053,
            0.7726298440211469,
        ],
    ),
    "ground-test-b": (
        [0.39796443937675263, 0.3985840890792661],
        [3.255295438460337, 0.0, 0.0, 3.262902008821528],
        [None, None, None, None, None, None],
    ),
    "flight-test-c": (
        [
            -0.0027530023387148323,
            -0.0021806540765367736,
            0.19994369634976034,
            0.24998235293503748,
            -0.2500288851933597,
            3.001141742648845,
            0.20277614776915934,
            0.20292076968663497,
        ],
        [
            1.873568010629,
            1.8916636938935878,
            1.8769559163495801,
            1.9000932235329506,
            1.3392182202665563,
            0.0,
            0.0,
            1.4367152154686977,
        ],
        [
            0.13457237434582006,
            0.13462059022552555,
            0.13515763859624078,
            0.13633546451633105,
            0.13773802101794197,
            0.13908054747626938,
        ],
    ),
}


@pytest.mark.parametrize("name", sorted(BEFORE))
def test_free_flight_is_bit_identical(name):
    q, u, rmse = BEFORE[name]
    a, s = Simulation(load_scenario(name), duration=0.1).run(None)
    assert a["q"][-1].tolist() == q
    assert a["u"][-1].tolist() == u
    got = [None if math.isnan(x) else float(x) for x in a["rmse"]]
    assert got == rmse
    assert not any(k in a for k in ("touch_phase", "rmse_local", "rmse_local_true"))

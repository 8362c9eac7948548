"""Fixtures of the CC baseline tests: a fresh cache directory, so the symbolic derivation runs
once per test session (about 5 s for the clamp, 50 s for the floating model on 2 cores)."""

import time

import numpy as np
import pytest

import tdacm
from tdacm.baselines import CCLagrangian


@pytest.fixture(scope="session")
def cc_cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    path = tmp_path_factory.mktemp("tdacm_cache")
    mp.setenv("TDACM_CACHE", str(path))
    yield path
    mp.undo()


@pytest.fixture(scope="session")
def gvs_floating():
    return tdacm.paper_system()


@pytest.fixture(scope="session")
def gvs_fixed():
    return tdacm.paper_system(fixed_base_pose=np.eye(4))


@pytest.fixture(scope="session")
def cc_fixed(cc_cache, gvs_fixed):
    return CCLagrangian.from_system(gvs_fixed)


@pytest.fixture(scope="session")
def cc_floating_timed(cc_cache, gvs_floating):
    t0 = time.perf_counter()
    cc = CCLagrangian.from_system(gvs_floating)
    return cc, time.perf_counter() - t0


@pytest.fixture(scope="session")
def cc_floating(cc_floating_timed):
    return cc_floating_timed[0]


def random_state(n, seed, scale=0.5):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=n) * scale
    qd = rng.normal(size=n)
    if n == 8:
        q[3:6] += [0.2, -0.1, 3.0]
    return q, qd

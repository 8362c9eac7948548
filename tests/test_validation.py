"""Bad input is refused with a message naming the parameter and the value."""

import numpy as np
import pytest

import tdacm


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"length": 0.0}, "length"),
        ({"length": -1.0}, "length"),
        ({"diameter": 0.0}, "diameter"),
        ({"density": -5.0}, "density"),
        ({"youngs_modulus": 0.0}, "youngs_modulus"),
        ({"poisson_ratio": 0.5}, "poisson_ratio"),
        ({"poisson_ratio": -1.0}, "poisson_ratio"),
        ({"damping": -1.0}, "damping"),
        ({"length": float("nan")}, "length"),
        ({"n_gauss": 0}, "n_gauss"),
        ({"magnus_order": 3}, "magnus_order"),
    ],
)
def test_rod_rejects_non_physical_parameters(kwargs, name):
    with pytest.raises(ValueError, match=name):
        tdacm.Rod(**kwargs)


def test_other_parameters_are_validated():
    with pytest.raises(ValueError, match="mass"):
        tdacm.Quadrotor(mass=0)
    with pytest.raises(ValueError, match="inertia"):
        tdacm.Quadrotor(inertia=(1, 2))
    with pytest.raises(ValueError, match="offsets"):
        tdacm.Tendons(offsets=[[0.1, 0.01, 0]])
    with pytest.raises(ValueError, match="orders"):
        tdacm.StrainBasis((0, 0))
    with pytest.raises(ValueError, match="attachment"):
        tdacm.TDACM(attachment=np.ones((4, 4)))
    with pytest.raises(ValueError, match="pose"):
        tdacm.FixedBase(pose=np.zeros((3, 3)))


def test_state_and_input_checks(paper=None):
    system = tdacm.paper_system()
    q = np.zeros(8)
    with pytest.raises(ValueError, match=r"q must have shape \(8,\)"):
        system.forward_dynamics(np.zeros(7), q)
    with pytest.raises(ValueError, match="q must be finite"):
        system.terms(np.full(8, np.nan), q)
    with pytest.raises(ValueError, match="non-negative"):
        system.forward_dynamics(q, q, [0, 0, 0, 0, -1.0, 0, 0, 0])
    with pytest.raises(ValueError, match=r"s must lie in \[0, L"):
        system.pose(q, 1.5)


def test_euler_singularity_is_reported_not_nan():
    system = tdacm.paper_system()
    q = np.zeros(8)
    q[1] = np.pi / 2
    with pytest.raises(tdacm.SingularConfigurationError, match="singularity"):
        system.forward_dynamics(q, np.zeros(8))
    with pytest.raises(tdacm.SingularConfigurationError):
        tdacm.simulate(system, q, duration=0.1)

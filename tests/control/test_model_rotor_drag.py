"""The controller's and the EKF's model of the drone's rotor drag: the plant's law, perturbed."""

import numpy as np
import pytest

from tdacm import paper_system
from tdacm.aero import Aerodynamics, Drag
from tdacm.control import EstimatedModel
from tdacm.estimation import kernels as EK
from tdacm.system.aero import aero_array, aero_generalized_force

Q = np.array([0.08, -0.05, 0.6, 0.1, 0.2, 3.0, 0.3, -0.2])
QD = np.array([0.1, -0.2, 0.05, 0.7, -0.4, 0.3, 0.5, -0.4])
K_R = (0.29, 0.25, 0.05)


@pytest.fixture(scope="module")
def system():
    return paper_system()


def test_nominal_rotor_damping_is_the_plants_rotor_drag(system):
    """With no model error, ``D_hat qd`` gains exactly the generalized force of the plant's
    linear rotor drag in still air (the kernels' drone drag with no body drag, no wake, no rod
    drag), at a tilted, yawed attitude."""
    air = Aerodynamics(
        drag=Drag(drone_linear=K_R, drone_cda=(0.0, 0.0, 0.0)), wake=False, rod_drag=False
    )
    tau_air = aero_generalized_force(system, Q, QD, np.zeros(system.n_u), aero_array(system, air))
    with_drag = EstimatedModel(system, 0.0, 0, rotor_drag=K_R).terms(Q, QD)
    without = EstimatedModel(system, 0.0, 0).terms(Q, QD)
    extra = (with_drag.D - without.D) @ QD
    np.testing.assert_allclose(extra, -tau_air, atol=1e-12)
    assert np.abs(extra[3:6]).max() > 0.05  # a real force, not two zeros
    np.testing.assert_array_equal(with_drag.M, without.M)


def test_rotor_damping_is_symmetric_psd_and_perturbed_within_level(system):
    model = EstimatedModel(system, 0.1, 5, rotor_drag=K_R)
    d = model.terms(Q, QD).D
    np.testing.assert_allclose(d, d.T, atol=1e-14)
    assert np.linalg.eigvalsh(d).min() > -1e-12
    ratio = model.rotor_drag / np.array(K_R)
    assert np.all(np.abs(ratio - 1.0) <= 0.1) and not np.allclose(ratio, 1.0)
    # knowing the drag leaves the other parameter draws unchanged
    plain = EstimatedModel(system, 0.1, 5)
    for name in ("d_m", "d_d", "d_k", "d_g"):
        np.testing.assert_array_equal(getattr(model, name), getattr(plain, name))


def test_filter_kernel_uses_the_same_damping(system):
    """The EKF's process model: ``qdd = M_hat^-1 (... - D_hat qd ...)`` with the rotor damping;
    with zero drag the kernel is the drag-free model bit for bit."""
    model = EstimatedModel(system, 0.1, 2, rotor_drag=K_R)
    s = model.system
    args = (s.model_arrays, s.loads.packed(), model.mass_scale, model.damping_scale)
    scales = (model.stiffness_scale, model.gravity_scale)
    u = np.array([1.9, 1.9, 1.9, 1.9, 0.4, 0.2, 0.1, 0.3])[: system.n_u]
    ad = np.zeros(system.n)
    a_drag, ok1 = EK.model_qdd(Q, QD, u, ad, *args, *scales, model.rotor_drag)
    a_none, ok2 = EK.model_qdd(Q, QD, u, ad, *args, *scales, np.zeros(3))
    assert ok1 and ok2
    t = model.terms(Q, QD)
    expected = np.linalg.solve(t.M, -model.rotor_damping(Q) @ QD[3:6] @ np.eye(3, system.n, 3))
    np.testing.assert_allclose(a_drag - a_none, expected, rtol=1e-9, atol=1e-12)
    plain = EstimatedModel(system, 0.1, 2)
    a_plain, _ = EK.model_qdd(
        Q, QD, u, ad, *args, plain.stiffness_scale, plain.gravity_scale, plain.rotor_drag
    )
    np.testing.assert_array_equal(a_plain, a_none)


def test_rotor_drag_rejected_on_a_fixed_base_and_when_negative():
    fixed = paper_system(fixed_base_pose=np.eye(4))
    with pytest.raises(ValueError, match="floating base"):
        EstimatedModel(fixed, 0.1, 0, rotor_drag=K_R)
    with pytest.raises(ValueError, match="rotor_drag"):
        EstimatedModel(paper_system(), 0.1, 0, rotor_drag=(0.1, -0.1, 0.0))

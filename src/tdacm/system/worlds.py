"""Many worlds of one robot: each world's rows of the model arrays (domain randomization).

A batch of worlds (:mod:`tdacm.batch`) shares the model arrays of the scenario's system
(:class:`~tdacm.system.kernels.ModelArrays`) except the rows that describe a world's own robot:
:class:`RobotRows` (its stiffness and damping, its sections' and drone's masses, its tendons'
offsets), stacked with a leading world axis; :func:`model_of_world` builds a world's
``ModelArrays`` from them inside compiled code.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .kernels import LOAD_DISTRIBUTED, ModelArrays


class RobotRows(NamedTuple):
    """A world's rows of the model arrays: ``stiffness``, ``damping`` (n, n), ``step_mass``
    (n_steps, 6), ``mb6`` (6,) the drone's inertia, ``tendon_d``, ``tendon_dd`` (n_g, n_a, 3)
    the tendons' offsets and their derivatives (stacked: a leading world axis)."""

    stiffness: np.ndarray
    damping: np.ndarray
    step_mass: np.ndarray
    mb6: np.ndarray
    tendon_d: np.ndarray
    tendon_dd: np.ndarray


#: the robot's relative factors of :func:`robot_rows`, in its columns' order
ROBOT_FACTORS = ("stiffness", "damping", "drone_mass", "rod_mass", "moment_arm")


def robot_rows(m, factors) -> RobotRows:
    """The stacked :class:`RobotRows` of the model arrays ``m`` (one arm) for the relative
    factors ``factors`` (N, 5) (:data:`ROBOT_FACTORS`): ``stiffness`` ``f_k K``, ``damping``
    ``f_d D``, ``step_mass`` with the rod sections' rows (distributed loads) times ``f_rho``,
    ``mb6`` with the mass entries times ``f_m`` (the inertias kept), ``tendon_d`` and
    ``tendon_dd`` times ``f_r``. The model is linear in each (``K`` in ``E`` at a fixed
    Poisson ratio, ``D`` in the viscosity, the sections' inertia in the density, the offsets
    in the tendon radius), so a factor of 1 gives the scenario's arrays bit for bit."""
    f = np.asarray(factors, float)
    n = f.shape[0]
    rod = m.step_load == LOAD_DISTRIBUTED
    mass_scale = np.where(rod[None, :], f[:, 3:4], 1.0)
    mb6 = np.tile(m.mb6, (n, 1))
    mb6[:, 3:6] = m.mb6[3:6][None, :] * f[:, 2:3]
    c = np.ascontiguousarray
    return RobotRows(
        c(m.stiffness[None] * f[:, 0, None, None]),
        c(m.damping[None] * f[:, 1, None, None]),
        c(m.step_mass[None] * mass_scale[:, :, None]),
        c(mb6),
        c(m.tendon_d[None] * f[:, 4, None, None, None]),
        c(m.tendon_dd[None] * f[:, 4, None, None, None]),
    )


@njit(cache=True)
def model_of_world(m, r):
    """``m`` (:class:`~tdacm.system.kernels.ModelArrays`) with one world's rows ``r`` (a
    :class:`RobotRows` of that world), built inside compiled code (numba constructs the
    NamedTuple; it has no ``_replace``); the run constants are the scenario's (the factors
    keep the zeros of ``stiffness`` and ``damping``). Rows of C-contiguous stacks keep the
    type of ``m``: the kernels run their compiled build."""
    return ModelArrays(
        m.floating, m.g_fixed, m.g_att, m.rod_steps, m.h, m.xi0s, m.bs, m.step_col, m.step_nc,
        m.step_w, r.step_mass, m.step_load, r.mb6, r.stiffness, r.damping, m.gamma, m.wq,
        m.xi0g, m.bg, m.g_col, m.g_nc, r.tendon_d, r.tendon_dd, m.tendon_on, m.step_z,
        m.step_c4, m.step_one, m.step_nzc, m.step_nzn, m.g_nzc, m.g_nzn, m.g_nzr, m.g_nzrn,
        m.kd_lo, m.kd_hi,
    )  # fmt: skip

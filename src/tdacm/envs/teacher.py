"""The servo's own IBVS twist at the worlds' current state, without acting: the teacher of
imitation learning on the vector env (:class:`~tdacm.envs.vector.TipServoVectorEnv`).

:func:`teacher_twists` gives, for each world, the twist ``v = -lambda J_img^+ e``
(eqs. (19)-(21), (39)) that the world's servo would command in the next step on the frame the
env has just observed: the same features as the observation (the detected points, or with the
robust servo the target filter's prediction after fusing the frame: the period's fusion,
which the step reuses), the same interaction matrix and gain. The course of the env's worlds
is not changed, so a learner's action can then be applied (DAgger: the teacher labels the states the learner
visits). NaN rows: no features (the servo would not servo on IBVS there).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..batch import engine as E
from ..batch import servo as S


@njit(cache=True, nogil=True)
def teacher_worlds(model, data, out, lo, hi):
    """The IBVS twist (N, 6) into ``out`` of the worlds ``lo <= w < hi`` (module docstring),
    as :func:`~tdacm.batch.engine.observe_worlds` finds their features."""
    sm = model.servo
    pv = np.empty((4, 2))
    zv = np.empty(4)
    pix = np.empty((4, 2))
    f = np.empty(6)
    e = np.empty(6)
    v = np.empty(6)
    for w in range(lo, hi):
        for i in range(6):
            out[w, i] = np.nan
        valid = E.world_view(model, data, w, pv, zv, pix) == S.SEEN
        if valid:
            S.ibvs_twist(pv, zv, sm, w, f, e, v)
            for i in range(6):
                out[w, i] = v[i]


def teacher_twists(venv) -> np.ndarray:
    """The IBVS twist (N, 6), in rad/s and m/s, each world of the vector env ``venv`` (or its
    ``unwrapped``) would command on its current observation (module docstring); divide by
    ``venv.unwrapped.scale`` for the action."""
    u = venv.unwrapped
    out = np.empty((u.num_envs, 6))
    E.parallel(teacher_worlds, (u.batch.model, u.batch.data, out), u.num_envs, u.threads)
    return out

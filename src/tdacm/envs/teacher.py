"""The servo's own IBVS twist at the worlds' current state, without acting: the teacher of
imitation learning on the vector env (:class:`~tdacm.envs.vector.TipServoVectorEnv`).

:func:`teacher_twists` gives, for each world, the twist ``v = -lambda J_img^+ e``
(eqs. (19)-(21), (39)) that the world's servo would command in the next step on the frame the
env has just observed: the servo's own view of the period (the detected points, or with the
robust servo the target filter's prediction after fusing the frame), its interaction matrix and
gain, as the servo's compiled step computed it (:func:`~tdacm.loop.servo.servo_perceive`). The
course of the env's worlds is not changed, so a learner's action can then be applied (DAgger:
the teacher labels the states the learner visits). NaN rows: no features (the servo would not
servo on IBVS there).
"""

from __future__ import annotations

import numpy as np


def teacher_twists(venv) -> np.ndarray:
    """The IBVS twists (N, 6 k) of the ``k`` arms, in rad/s and m/s, each world of the vector
    env ``venv`` (or its ``unwrapped``) would command on its current observation (module
    docstring); divide by ``venv.unwrapped.scale`` for the action."""
    out = venv.unwrapped.batch.data.servo_out  # (N, arms, ...)
    twists = np.where(out.seen[:, :, :1], out.ibvs_twist, np.nan)
    return twists.reshape(twists.shape[0], -1)

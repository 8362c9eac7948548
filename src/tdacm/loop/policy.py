"""A learned servoing policy as a block of the closed loop: the observation it sees, the saved
policy file and the servo that runs it in place of the IBVS twist.

**Observation** (:func:`observation`, the one definition the Gymnasium envs and
:class:`PolicyServo` share; float32, size :func:`observation_size` ``= 15 + 2 n`` for a robot of
``n`` coordinates, each entry clipped to ``[-OBS_CLIP, OBS_CLIP]``, NaN set to 0):

* ``[0:6]`` the advanced-feature error ``p* - p*_d`` (eqs. (19)-(20)) divided by
  ``FEATURE_SCALE``;
* ``[6:14]`` the four normalized image points in the servo camera (C_V, eq. (18); C_L for a
  fixed base) divided by C_L's half-extent in normalized coordinates (``cx / fx``,
  ``cy / fy``): +-1 is the image border;
* ``[14]`` the flag "features available" (0 or 1); entries ``[0:14]`` are zero without;
* ``[15:15+n]`` the state estimate's offset from the desired configuration,
  ``(q_hat - q*) / q_scale`` (:func:`state_scales`: ``ANGLE_SCALE`` rad for the drone's
  angles, ``POSITION_SCALE`` m for its position, ``STRAIN_SCALE`` 1/m for the strains);
* ``[15+n:]`` the velocity estimate ``qdot_hat / q_scale`` (per second).

The features are those the servo works on: the detected points (``ibvs.features =
"measured"``) or the target filter's prediction (``"predicted"``, the robust servo).

**Policy file** (:func:`save_policy`, :func:`load_policy`): one ``.npz`` holding the
observation scaling ``obs_mean``, ``obs_var`` (the input is ``x = clip((obs - mean) /
(sqrt(var) + 1e-8), -5, 5)``), the layers and ``meta``, a JSON text: the format, the
architecture, the observation size, the robot's signature and description, the action scale
(``max_angular`` rad/s, ``max_linear`` m/s) and what it was trained on. Two architectures
(``meta["architecture"]``):

* ``"tanh-mlp"`` (format 1): the MLP's layers ``W0, b0, ..., Wk, bk``, ``tanh`` after every
  layer, the last one included: the action ``a`` in ``[-1, 1]^6``;
* ``"linear+mlp"`` (format 2): an exact linear path ``L, c`` beside the MLP ``W0, b0, ...,
  Wk, bk`` (``tanh`` after the hidden layers, the last one linear):
  ``a = clip(clip(x L + c, -1, 1) + mlp(x), -1, 1)``. Near the goal the servo's twist is an
  affine map of the observation (``-lambda J^+ e`` with a nearly constant ``J``), which the
  linear path holds exactly; the MLP adds the rest, a bounded correction of the clipped
  linear map far from the goal.

Running it needs numpy only.

**The block** (:class:`PolicyServo`): the scenario's servo (its mode switch, features,
recovery, joint-rate mapping and command shaping) with the policy's twist ``action * scale``
in place of the IBVS twist (``[servo] policy``).
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import npz_problem

#: Observation scaling (module docstring).
FEATURE_SCALE = 0.5
ANGLE_SCALE = 0.5  # rad
POSITION_SCALE = 1.0  # m
STRAIN_SCALE = 1.0  # 1/m
OBS_CLIP = 5.0
OBSERVATION_SCALES = {
    "feature_error": FEATURE_SCALE,
    "angle": ANGLE_SCALE,
    "position": POSITION_SCALE,
    "strain": STRAIN_SCALE,
    "clip": OBS_CLIP,
}
#: the policy input's standardization: ``clip((obs - mean) / (sqrt(var) + SCALER_EPS), +-5)``
SCALER_EPS = 1e-8
SCALER_CLIP = 5.0
#: the policy file's format versions (``meta["format"]``) and their architectures
POLICY_FORMATS = {1: "tanh-mlp", 2: "linear+mlp"}


def observation_size(n: int) -> int:
    """The observation's size for a robot of ``n`` coordinates."""
    return 15 + 2 * int(n)


def state_scales(n: int, floating: bool) -> np.ndarray:
    """``q_scale`` (n,) of the observation's state entries (module docstring)."""
    q_scale = np.full(int(n), STRAIN_SCALE)
    if floating:
        q_scale[:3] = ANGLE_SCALE
        q_scale[3:6] = POSITION_SCALE
    return q_scale


def observation(error, points, seen, q, qd, q_star, q_scale, point_scale) -> np.ndarray:
    """The observation (module docstring) of ``N`` worlds: ``error`` (N, 6), ``points``
    (N, 4, 2) (either may hold NaN or anything where ``seen`` (N,) is false), the estimate
    ``q``, ``qd`` (N, n); ``q_star``, ``q_scale`` (n,); ``point_scale`` (2,). Returns
    (N, 15 + 2 n) float32, NaN entries set to 0, clipped to ``+-OBS_CLIP``."""
    seen = np.asarray(seen, bool)
    N, n = seen.shape[0], np.shape(q)[1]
    obs = np.zeros((N, observation_size(n)))
    with np.errstate(invalid="ignore"):
        obs[:, :6] = np.where(seen[:, None], np.asarray(error, float) / FEATURE_SCALE, 0.0)
        pts = (np.asarray(points, float) / point_scale).reshape(N, 8)
        obs[:, 6:14] = np.where(seen[:, None], pts, 0.0)
    obs[:, 14] = seen
    obs[:, 15 : 15 + n] = (np.asarray(q, float) - q_star) / q_scale
    obs[:, 15 + n :] = np.asarray(qd, float) / q_scale
    np.nan_to_num(obs, copy=False, nan=0.0)
    np.clip(obs, -OBS_CLIP, OBS_CLIP, out=obs)
    return obs.astype(np.float32)


# ----------------------------------------------------------------------------- the file
class PolicyError(ValueError):
    """A policy file that cannot be read or does not fit (one line)."""


@dataclass(frozen=True)
class Policy:
    """A saved deterministic policy ``obs (.., m) -> action (.., 6)`` in ``[-1, 1]``
    (module docstring), evaluated with numpy. ``linear``: ``(L, c)`` of the linear path, or
    ``None`` (the ``"tanh-mlp"`` architecture)."""

    weights: tuple
    biases: tuple
    obs_mean: np.ndarray
    obs_std: np.ndarray
    meta: dict
    linear: tuple | None = None

    @property
    def observation_size(self) -> int:
        return int(self.obs_mean.shape[0])

    @property
    def twist_scale(self) -> np.ndarray:
        """``[max_angular] * 3 + [max_linear] * 3``: the twist of an action."""
        a = self.meta["action_scale"]
        return np.array([a["max_angular"]] * 3 + [a["max_linear"]] * 3, float)

    def __call__(self, obs) -> np.ndarray:
        x = np.asarray(obs, float)
        x = np.clip((x - self.obs_mean) / self.obs_std, -SCALER_CLIP, SCALER_CLIP)
        if self.linear is None:
            for W, b in zip(self.weights, self.biases, strict=True):
                x = np.tanh(x @ W + b)
            return x
        L, c = self.linear
        h = x
        for i, (W, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = h @ W + b
            if i < len(self.weights) - 1:
                h = np.tanh(h)
        return np.clip(np.clip(x @ L + c, -1.0, 1.0) + h, -1.0, 1.0)


def save_policy(path, weights, biases, obs_mean, obs_var, meta: dict, linear=None) -> Path:
    """Write a policy file (module docstring): the layers ``weights[i]`` (m_i, m_{i+1}) and
    ``biases[i]``, the observation scaling, ``meta`` (JSON-serializable; must hold ``robot``
    and ``action_scale``) and ``linear``: ``(L, c)`` of the linear path (format 2,
    ``"linear+mlp"``), or ``None`` (format 1, ``"tanh-mlp"``). The linear path is stored in
    float64 (its precision is the policy's near the goal), the MLP in float32."""
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_suffix(".npz")
    arrays = {}
    for i, (W, b) in enumerate(zip(weights, biases, strict=True)):
        arrays[f"W{i}"] = np.asarray(W, np.float32)
        arrays[f"b{i}"] = np.asarray(b, np.float32)
    fmt = 1 if linear is None else 2
    if linear is not None:
        arrays["L"] = np.asarray(linear[0], np.float64)
        arrays["c"] = np.asarray(linear[1], np.float64)
    meta = {
        **meta,
        "format": fmt,
        "architecture": POLICY_FORMATS[fmt],
        "observation_size": int(np.shape(obs_mean)[0]),
        "observation_scales": OBSERVATION_SCALES,
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(
        path,
        meta=np.array(json.dumps(meta)),
        obs_mean=np.asarray(obs_mean, np.float32),
        obs_var=np.asarray(obs_var, np.float32),
        **arrays,
    )
    return path


def load_policy(path) -> Policy:
    """The :class:`Policy` of a file written by :func:`save_policy`; :class:`PolicyError`
    (one line) if it is missing or malformed."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            k = sum(1 for name in z.files if name.startswith("W"))
            W = tuple(z[f"W{i}"].astype(float) for i in range(k))
            b = tuple(z[f"b{i}"].astype(float) for i in range(k))
            mean = z["obs_mean"].astype(float)
            std = np.sqrt(z["obs_var"].astype(float)) + SCALER_EPS
            linear = (z["L"].astype(float), z["c"].astype(float)) if "L" in z.files else None
    except FileNotFoundError:
        raise PolicyError(f"no such file {str(path)!r}") from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise PolicyError(f"{str(path)!r} is not a policy file ({npz_problem(exc)})") from None
    fmt = meta.get("format")
    if fmt not in POLICY_FORMATS or (linear is not None) != (fmt == 2):
        raise PolicyError(
            f"{str(path)!r}: policy format {fmt!r}, expected one of {sorted(POLICY_FORMATS)} "
            f"(2 with a linear path L, c)"
        )
    m = mean.shape[0] if mean.ndim == 1 else -1
    shapes_ok = k >= 1 and std.shape == (m,) and W[0].ndim == 2 and W[0].shape[0] == m
    shapes_ok = shapes_ok and W[-1].ndim == 2 and W[-1].shape[1] == 6
    for i in range(k):
        shapes_ok = shapes_ok and W[i].ndim == 2 and b[i].shape == (W[i].shape[1],)
        if i:
            shapes_ok = shapes_ok and W[i].shape[0] == W[i - 1].shape[1]
    if linear is not None:
        shapes_ok = shapes_ok and linear[0].shape == (m, 6) and linear[1].shape == (6,)
    arrays = (*W, *b, mean, std, *(linear or ()))
    if not shapes_ok or not all(np.isfinite(a).all() for a in arrays):
        raise PolicyError(f"{str(path)!r}: malformed layers or observation scaling")
    if meta.get("observation_scales") != OBSERVATION_SCALES:
        raise PolicyError(
            f"{str(path)!r}: trained with observation scales {meta.get('observation_scales')}, "
            f"this version uses {OBSERVATION_SCALES}"
        )
    return Policy(W, b, mean, std, meta, linear)


# ----------------------------------------------------------------------------- the block
class PolicyServo:
    """The servo ``servo`` (a :class:`~.servo.VisualServo` or
    :class:`~.servo.RobustServo`) with ``policy``'s twist in place of the IBVS twist
    (the servo protocol of :mod:`.protocols`).

    Per period: the servo's own first part (:meth:`~.servo.VisualServo.perceive`: the mode
    switch, the features in C_V), the :func:`observation` of those features and the state
    estimate, the policy's action times its ``twist_scale``, then the servo's end of period
    (:meth:`~.servo.VisualServo.command`: in IBVS mode, the mapping ``qdot_d = (J_L^L)^+ Ad
    v`` and the command shaping; the recovery with C_G otherwise). A ``twist`` passed to
    :meth:`step` (an external command) replaces the policy's as it replaces the IBVS twist.
    """

    def __init__(self, servo, policy: Policy, q_star, point_scale):
        self.servo = servo
        self.policy = policy
        s = servo.system
        self.q_star = np.asarray(q_star, float)
        self.q_scale = state_scales(s.n, s.floating)
        self.point_scale = np.asarray(point_scale, float)
        self.scale = policy.twist_scale
        self.last_observation = None

    def __getattr__(self, name):  # the wrapped servo's state (q_d, switch, ...)
        if name == "servo":
            raise AttributeError(name)
        return getattr(self.servo, name)

    @property
    def mode(self) -> str:
        return self.servo.mode

    @property
    def desired_points(self) -> np.ndarray:
        return self.servo.desired_points

    def reset(self, q0, first_view=None) -> None:
        self.servo.reset(q0, first_view)
        self.last_observation = None

    def observe(self, seen, points, error, q, qd) -> np.ndarray:
        """The observation (m,) of one period (:func:`observation`)."""
        err = np.zeros(6) if error is None else error
        pts = np.zeros((4, 2)) if points is None else points
        return observation(
            err[None], np.asarray(pts)[None], [bool(seen)], np.asarray(q)[None],
            np.asarray(qd)[None], self.q_star, self.q_scale, self.point_scale,
        )[0]  # fmt: skip

    def step(self, t, dt, view, gview, est, twist=None, **kw):
        parts = self.servo.perceive(t, dt, view, est)
        _, _, seen, _, points, _, error, _, _ = parts
        if twist is None:
            obs = self.last_observation = self.observe(seen, points, error, est.q, est.qd)
            twist = np.clip(self.policy(obs), -1.0, 1.0) * self.scale
        return self.servo.command(t, dt, est.q, gview, twist, *parts)

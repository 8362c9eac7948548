"""The options of the servoing task, one record for the single env
(:class:`~tdacm.envs.servo.TipServoEnv`) and the vector env
(:class:`~tdacm.envs.vector.TipServoVectorEnv`): each default is written here once.

Both constructors take these options as keywords (what ``gym.make``/``gym.make_vec`` pass) or a
ready :class:`EnvOptions` as ``options=``. The values are checked once, here, with a
``ValueError`` naming the option.

Domain randomization (:class:`Randomization`, off by default): each field is the half-width
(relative, for the physical parameters) or the upper end (for the sensor imperfections) of a
range a world draws its value from at every reset. The vector env draws them from each
world's own generator (:meth:`Randomization.draw`) and gives them to the world as per-world
parameters of the batched engine (:class:`~tdacm.batch.params.WorldParams`). The single env
(the block loop, one plant model built with the scenario) refuses a non-zero range with one
line naming the option instead of ignoring it; fixed values are scenario keys
(``overrides={"sensors": {"pixel_noise": 1.0}}``). The initial pose spread is supported:
``init_noise`` is one standard deviation for every coordinate or one per coordinate (the
robustness campaigns' spread of ``paper-in-fov`` is ``[0, 0, 0.05, 0.1, 0.1, 0.2, 0.05,
0.05]``, ``examples/campaigns/paper-in-fov-200.toml``).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..sim.runner import SUCCESS_RMSE

#: The upper bounds of the randomization ranges (module docstring).
RANDOMIZATION_LIMITS = {
    "stiffness": 0.1,
    "damping": 0.1,
    "masses": 0.1,
    "moment_arm": 0.1,
    "pixel_noise": 2.0,
    "dropout": 0.1,
    "latency": 2,
}


@dataclass(frozen=True)
class Randomization:
    """Ranges drawn per world at each reset (module docstring): ``stiffness``, ``damping``
    (the rod's K and D), ``masses`` (the drone's and the rod's), ``moment_arm`` (the
    tendons' moment arms): relative half-widths in ``[0, 0.1]`` (a value ``x`` scales by a
    factor uniform in ``[1 - x, 1 + x]``); ``pixel_noise`` (px, ``[0, 2]``), ``dropout``
    (``[0, 0.1]``), ``latency`` (frames, ``0..2``): upper ends of ranges starting at 0 (a
    drawn sensor value replaces the scenario's)."""

    stiffness: float = 0.0
    damping: float = 0.0
    masses: float = 0.0
    moment_arm: float = 0.0
    pixel_noise: float = 0.0
    dropout: float = 0.0
    latency: int = 0

    def __post_init__(self):
        for name, top in RANDOMIZATION_LIMITS.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not 0 <= v <= top:
                raise ValueError(f"randomize.{name} must be a number in [0, {top}], got {v!r}")
        if self.latency != int(self.latency):
            raise ValueError(
                f"randomize.latency must be a whole number of frames, got {self.latency!r}"
            )

    @property
    def active(self) -> tuple[str, ...]:
        """The names of the non-zero ranges."""
        return tuple(n for n in RANDOMIZATION_LIMITS if getattr(self, n) != 0)

    def refuse(self, engine: str) -> None:
        """Raise ``ValueError`` (one line) naming the first non-zero range: ``engine``
        draws no parameters at reset."""
        if self.active:
            name = self.active[0]
            raise ValueError(
                f"randomize.{name}: {engine} runs one model built from the scenario and draws "
                f"no parameters at reset; use the vector env (gym.make_vec), set it to 0, or "
                f"fix the value with a scenario override"
            )

    def draw(self, rng) -> dict:
        """One world's draws from ``rng`` (a ``numpy.random.Generator``), in the order of
        :data:`RANDOMIZATION_LIMITS` (``masses``: the drone's, then the rod's), only for the
        non-zero ranges: the fields of :class:`~tdacm.batch.params.WorldParams` (the robot's
        as factors uniform in ``[1 - x, 1 + x]``, the sensors' uniform in ``[0, x]``, the
        latency a whole number of frames in ``0..x``), each a one-element list."""
        out = {}
        for name in self.active:
            x = getattr(self, name)
            if name == "masses":
                out["drone_mass"] = [rng.uniform(1.0 - x, 1.0 + x)]
                out["rod_mass"] = [rng.uniform(1.0 - x, 1.0 + x)]
            elif name in ("stiffness", "damping", "moment_arm"):
                out[name] = [rng.uniform(1.0 - x, 1.0 + x)]
            elif name == "latency":
                out[name] = [int(rng.integers(0, int(x) + 1))]
            else:
                out[name] = [rng.uniform(0.0, x)]
        return out


@dataclass(frozen=True)
class EnvOptions:
    """The task's options (:mod:`tdacm.envs.servo` documents their meaning): the scenario and
    its ``overrides`` (a nested dict of scenario keys; ``safety`` false turns the safety
    monitor off), the action (``action_type``, scaled by ``max_angular`` rad/s and
    ``max_linear`` m/s), the episode (``max_steps`` control periods; ``init_noise``, the
    initial offset's standard deviation on q, a number or one per coordinate), the reward
    and endings (``success_rmse``, ``success_bonus``, ``lost_penalty``, ``max_lost``;
    ``hold_success``: success is judged at the episode's last step, the normalized RMSE at or
    below ``success_rmse`` there and at every step since it first got there, instead of
    ending the episode when it first gets there) and the
    domain randomization ``randomize`` (a :class:`Randomization` or a dict of its fields)."""

    scenario: str = "paper-in-fov"
    action_type: str = "twist"
    max_steps: int = 250
    init_noise: float | tuple[float, ...] = 0.02
    success_rmse: float = SUCCESS_RMSE
    success_bonus: float = 10.0
    lost_penalty: float = 1.0
    max_lost: int = 10
    max_angular: float = 0.5
    max_linear: float = 0.5
    overrides: dict | None = None
    safety: bool = False
    hold_success: bool = False
    randomize: Randomization = field(default_factory=Randomization)

    def __post_init__(self):
        if isinstance(self.randomize, dict):
            names = {f.name for f in dataclasses.fields(Randomization)}
            unknown = sorted(set(self.randomize) - names)
            if unknown:
                raise ValueError(
                    f"randomize.{unknown[0]}: unknown, expected one of {sorted(names)}"
                )
            object.__setattr__(self, "randomize", Randomization(**self.randomize))
        elif not isinstance(self.randomize, Randomization):
            raise ValueError(f"randomize must be a Randomization or a dict, got {self.randomize!r}")
        if self.action_type not in ("twist", "actuators"):
            raise ValueError(
                f"action_type must be 'twist' or 'actuators', got {self.action_type!r}"
            )
        if int(self.max_steps) != self.max_steps or self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps!r}")
        if int(self.max_lost) != self.max_lost or self.max_lost < 1:
            raise ValueError(f"max_lost must be >= 1, got {self.max_lost!r}")
        noise = self.init_noise
        if isinstance(noise, list | tuple):
            noise = tuple(float(x) for x in noise)
            object.__setattr__(self, "init_noise", noise)
        values = noise if isinstance(noise, tuple) else (noise,)
        if not values or not all(math.isfinite(x) and x >= 0 for x in values):
            raise ValueError(f"init_noise must be finite and >= 0, got {self.init_noise!r}")
        for name in ("success_rmse", "max_angular", "max_linear"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        for name in ("success_bonus", "lost_penalty"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")

    @classmethod
    def of(cls, options: EnvOptions | None, kwargs: dict) -> EnvOptions:
        """``options`` with ``kwargs`` replacing some of its fields (a ``ValueError`` names
        an unknown keyword)."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(kwargs) - names)
        if unknown:
            raise ValueError(
                f"{unknown[0]}: not an option of the env, expected one of {sorted(names)}"
            )
        base = cls() if options is None else options
        return dataclasses.replace(base, **kwargs) if kwargs else base

    def initial_std(self, n: int):
        """The initial offset's standard deviation, one per coordinate (n,)."""
        import numpy as np

        if isinstance(self.init_noise, tuple):
            if len(self.init_noise) != n:
                raise ValueError(
                    f"init_noise: one standard deviation per coordinate ({n}), got "
                    f"{len(self.init_noise)}"
                )
            return np.asarray(self.init_noise, float)
        return np.full(n, float(self.init_noise))


def clip_action(a: np.ndarray, low, high) -> np.ndarray:
    """``a`` clipped to the action space ``[low, high]``, with one ``UserWarning`` (Python
    shows it once per place) when an entry lay outside: an agent's out-of-range action is a
    bug to know of, not an error that ends its training. NaN entries stay NaN (the vector
    env's row of NaN: the servo's own twist)."""
    with np.errstate(invalid="ignore"):
        outside = bool(np.any((a < low) | (a > high)))
    if outside:
        warnings.warn(
            "action outside the action space: clipped to its bounds (docs/env.md, Actions)",
            UserWarning,
            stacklevel=3,
        )
    return np.clip(a, low, high)

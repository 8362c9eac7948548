"""Per-world parameters of a batch (domain randomization), as a structure of arrays.

A :class:`WorldParams` gives each world of a batch its own robot, C_L imperfections and target
pose; a field left ``None`` is the scenario's value for every world. The robot's parameters
are relative factors on the scenario's model arrays (each world's rows of the
:class:`~tdacm.batch.engine.BatchModel` stacks, :func:`~tdacm.system.worlds.robot_rows`), each one the model a
scenario with that parameter scaled builds (tested against the block loop):

=================  ==========================================  ==============================
field              scales                                      scenario key
=================  ==========================================  ==============================
``stiffness``      the rod's stiffness ``K`` (eq. (18))        ``robot.rod.youngs_modulus``
``damping``        the rod's damping ``D`` (eq. (17))          ``robot.rod.damping``
``drone_mass``     the drone's mass (not its inertia)          ``robot.drone.mass``
``rod_mass``       the rod's sections' inertia (not the tip)   ``robot.rod.density``
``moment_arm``     the tendons' offsets from the centreline    ``robot.tendons.radius``
=================  ==========================================  ==============================

The sensors' and the target's are values: ``pixel_noise`` (px), ``dropout`` (probability),
``latency`` (frames) as ``[sensors]``; ``target_tilt_deg`` (N, 2), ``target_yaw_deg`` and
``target_xy`` (N, 2, the box's centre) as ``[scene]``. The controller's model follows the
world's robot (its ``[model] perturbation`` is relative to it), as the block loop built on
that world's scenario does.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..system.worlds import ROBOT_FACTORS

#: the C_L imperfections, in the column order of :attr:`tdacm.batch.servo.ServoModel.sensor`
SENSOR_FIELDS = ("pixel_noise", "dropout", "latency")
#: the target's pose
TARGET_FIELDS = ("target_tilt_deg", "target_yaw_deg", "target_xy")
#: the largest latency the engine buffers (frames; the robust servo keeps 64 C_L poses)
MAX_LATENCY = 63

_WIDTH = {"target_tilt_deg": 2, "target_xy": 2}


@dataclass(frozen=True)
class WorldParams:
    """Per-world parameters (module docstring): each field ``None`` or one value per world
    ((N,) arrays; (N, 2) for ``target_tilt_deg`` and ``target_xy``). Checked once here:
    ``ValueError`` naming the field."""

    stiffness: np.ndarray | None = None
    damping: np.ndarray | None = None
    drone_mass: np.ndarray | None = None
    rod_mass: np.ndarray | None = None
    moment_arm: np.ndarray | None = None
    pixel_noise: np.ndarray | None = None
    dropout: np.ndarray | None = None
    latency: np.ndarray | None = None
    target_tilt_deg: np.ndarray | None = None
    target_yaw_deg: np.ndarray | None = None
    target_xy: np.ndarray | None = None

    def __post_init__(self):
        n = None
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            a = np.array(v, float)
            width = _WIDTH.get(f.name)
            if width is not None:
                a = np.atleast_2d(a)
                ok = a.ndim == 2 and a.shape[1] == width
            else:
                a = np.atleast_1d(a)
                ok = a.ndim == 1
            if not ok:
                raise ValueError(f"{f.name}: one value{'' if width is None else ' pair'} per world")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{f.name}: values must be finite")
            if n is None:
                n = a.shape[0]
            elif a.shape[0] != n:
                raise ValueError(f"{f.name}: {a.shape[0]} worlds, another field has {n}")
            if f.name in ROBOT_FACTORS and np.any(a <= 0):
                raise ValueError(f"{f.name}: factors must be > 0")
            if f.name == "pixel_noise" and np.any(a < 0):
                raise ValueError("pixel_noise: must be >= 0 px")
            if f.name == "dropout" and np.any((a < 0) | (a >= 1)):
                raise ValueError("dropout: a probability in [0, 1)")
            if f.name == "latency" and (
                np.any(a != np.round(a)) or np.any((a < 0) | (a > MAX_LATENCY))
            ):
                raise ValueError(f"latency: whole frames in [0, {MAX_LATENCY}]")
            if f.name == "target_tilt_deg" and np.any(np.abs(a) > 30.0):
                raise ValueError("target_tilt_deg: within +-30 deg")
            object.__setattr__(self, f.name, a)

    @property
    def n_worlds(self) -> int | None:
        """The number of worlds the fields give (``None``: no field set)."""
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if v is not None:
                return v.shape[0]
        return None

    def given(self, names) -> bool:
        """Whether any of the fields ``names`` is set."""
        return any(getattr(self, k) is not None for k in names)

    def robot_factors(self, n: int) -> np.ndarray:
        """(n, 5) the robot's factors by :data:`ROBOT_FACTORS` (1 where not set)."""
        out = np.ones((n, len(ROBOT_FACTORS)))
        for j, k in enumerate(ROBOT_FACTORS):
            v = getattr(self, k)
            if v is not None:
                out[:, j] = v
        return out

    def sensor_rows(self, nominal) -> np.ndarray:
        """(n, 3) the C_L imperfections by :data:`SENSOR_FIELDS`, ``nominal`` (3,) where not
        set (n: :attr:`n_worlds`)."""
        out = np.tile(np.asarray(nominal, float), (self.n_worlds, 1))
        for j, k in enumerate(SENSOR_FIELDS):
            v = getattr(self, k)
            if v is not None:
                out[:, j] = v
        return out

    def take(self, idx) -> WorldParams:
        """The worlds ``idx`` (an index array) of these parameters."""
        idx = np.asarray(idx, np.int64)
        return WorldParams(**{
            f.name: None if getattr(self, f.name) is None else getattr(self, f.name)[idx]
            for f in dataclasses.fields(self)
        })  # fmt: skip

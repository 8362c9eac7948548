"""Recordings the fit reads: what a lab measures, on one time base.

A :class:`Recording` holds, at the sample times ``t`` (uniform spacing):

* ``u``: the inputs as measured: the four rotor thrust commands (flying base) then the tendon
  tensions (load cells), held over each sample interval;
* ``drone``: the drone's pose from motion capture (4x4 per sample; ``None`` for a clamped rod);
* ``tip``: the tip body's pose from motion capture (a rigid marker set on the tip);
* ``pixels`` (optional): the tip camera's four target feature points (pixels), with the scene's
  ``target_points`` (4, 3) and the camera;
* ``added``: known additions to parameters during the experiment (a clip-on calibration mass
  ``{"tip_mass": 0.02}``), read from the ``[added]`` table of ``experiment.toml`` in a run
  folder or of ``NAME.experiment.toml`` beside ``NAME.mcap``.

The strains are never read: the fit compares poses (and pixels) only.

Sources: a run folder (``timeseries.npz`` with ``t``, ``q``, ``u`` and its ``scenario.toml``;
the poses are those of ``q``, noise-free, unless a ``measurements.npz`` written by
:mod:`tdacm.identify.experiments` holds measured ones) or an MCAP file imported through
:func:`tdacm.recording.read_mcap` with a topic map naming the signals ``drone_pose``,
``tip_pose``, ``tensions`` and ``thrusts`` (a tdacm export's topics by default).
"""

from __future__ import annotations

import logging
import tomllib
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .._validate import npz_problem
from .model import IdentModel

log = logging.getLogger(__name__)


class RecordingInputError(ValueError):
    """A recording that cannot be used for identification; the message names the problem."""


@dataclass
class Recording:
    """One experiment's measurements (module docstring) and the model structure it belongs to."""

    name: str
    t: np.ndarray
    u: np.ndarray
    model: IdentModel
    tip: np.ndarray | None = None
    drone: np.ndarray | None = None
    pixels: np.ndarray | None = None
    target_points: np.ndarray | None = None
    camera: object = None
    truth: dict = field(default_factory=dict)  # hidden parameters of a synthetic recording
    q: np.ndarray | None = None  # the true states when known (never used by the fit)
    added: dict = field(default_factory=dict)  # known additions, e.g. a clip-on tip mass (kg)

    def __post_init__(self):
        self.t = np.asarray(self.t, float)
        self.u = np.asarray(self.u, float)
        n = len(self.t)
        if n < 3:
            raise RecordingInputError(f"{self.name}: fewer than 3 samples")
        dt = np.diff(self.t)
        if np.any(dt <= 0) or np.ptp(dt) > 1e-6 * max(dt.mean(), 1e-12) + 1e-9:
            raise RecordingInputError(f"{self.name}: the sample times must be uniformly spaced")
        sysm = self.model.system
        if self.u.shape != (n, sysm.n_u):
            raise RecordingInputError(
                f"{self.name}: u must be ({n}, {sysm.n_u}) (thrusts then tensions), got "
                f"{self.u.shape}"
            )
        if self.tip is None and self.pixels is None:
            raise RecordingInputError(f"{self.name}: no tip pose and no camera pixels")
        if self.model.floating and self.drone is None:
            raise RecordingInputError(f"{self.name}: a flying base needs the drone pose")

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def decimated(self, k: int) -> Recording:
        """Every ``k``-th sample, the inputs averaged over the ``k`` samples they now hold
        for (the mean of a zero-order hold); the poses and pixels are the samples'."""
        if k == 1:
            return self
        m = len(self.t) // k
        cut = lambda a: None if a is None else a[: m * k : k]  # noqa: E731
        u = self.u[: m * k].reshape(m, k, -1).mean(axis=1)
        return Recording(
            self.name, self.t[: m * k : k], u, self.model, cut(self.tip), cut(self.drone),
            cut(self.pixels), self.target_points, self.camera, self.truth, cut(self.q),
            self.added,
        )  # fmt: skip

    def window(self, t0: float, t1: float) -> Recording:
        """The samples with ``t0 <= t < t1``."""
        k = (self.t >= t0 - 1e-9) & (self.t < t1 - 1e-9)
        cut = lambda a: None if a is None else a[k]  # noqa: E731
        return Recording(
            self.name, self.t[k], self.u[k], self.model, cut(self.tip), cut(self.drone),
            cut(self.pixels), self.target_points, self.camera, self.truth, cut(self.q),
            self.added,
        )  # fmt: skip

    def with_basis(self, basis: str) -> Recording:
        """The same measurements on the robot with the rod's strain basis ``basis``."""
        model = self.model.with_basis(basis)
        q = self.q if self.q is not None and self.q.shape[1] == model.system.n else None
        return replace(self, model=model, q=q)

    def values(self, values: dict) -> dict:
        """The model's values during this experiment: ``values`` plus the known additions."""
        v = self.model.values(values)
        for k, a in self.added.items():
            v[k] += a
        return v


def pose7_to_matrix(v: np.ndarray) -> np.ndarray:
    """(T, 7) ``x, y, z, qx, qy, qz, qw`` -> (T, 4, 4)."""
    v = np.asarray(v, float)
    g = np.tile(np.eye(4), (len(v), 1, 1))
    g[:, :3, :3] = Rotation.from_quat(v[:, 3:]).as_matrix()
    g[:, :3, 3] = v[:, :3]
    return g


def matrix_to_pose7(g: np.ndarray) -> np.ndarray:
    g = np.asarray(g, float)
    return np.column_stack([g[:, :3, 3], Rotation.from_matrix(g[:, :3, :3]).as_quat()])


def model_of_scenario(scenario):
    """``(IdentModel, world)`` of a scenario (name, path or :class:`~tdacm.sim.Scenario`)."""
    from ..sim import build_world, load_scenario

    sc = load_scenario(scenario) if isinstance(scenario, str | Path) else scenario
    world = build_world(sc)
    robot = world.robot
    # C_L's offset beyond the tip is the translation of its mount along the backbone
    offset = float(robot.tip_mount[0, 3])
    return IdentModel(robot.system, robot.tip_mount, offset), world


def load_recording(path, scenario=None, topic_map=None) -> Recording:
    """A :class:`Recording` from a run folder or an MCAP file (module docstring).

    ``scenario`` (name, path or Scenario) gives the robot's structure and nominal values; by
    default the folder's ``scenario.toml`` (for an MCAP file: a ``scenario.toml`` beside it)."""
    path = Path(path)
    if path.is_dir():
        return _load_folder(path, scenario)
    if path.suffix == ".mcap" and path.is_file():
        from ..recording import RecordingError, check_mcap

        try:
            check_mcap(path)  # before the scenario is looked for: the file itself first
        except RecordingError as exc:
            raise RecordingInputError(str(exc).replace("FILE", "RECORDING", 1)) from None
        return _load_mcap(path, scenario, topic_map)
    raise RecordingInputError(f"RECORDING {path} is neither a run folder nor an .mcap file")


def _scenario_for(path: Path, scenario):
    if scenario is not None:
        return scenario
    cand = path / "scenario.toml" if path.is_dir() else path.parent / "scenario.toml"
    if not cand.is_file():
        raise RecordingInputError(
            f"RECORDING {path}: no scenario.toml beside it; give the robot with --scenario"
        )
    return cand


def _load_folder(path: Path, scenario) -> Recording:
    npz = path / "timeseries.npz"
    if not npz.is_file():
        raise RecordingInputError(f"RECORDING {path} has no timeseries.npz")
    model, world = model_of_scenario(_scenario_for(path, scenario))
    arrays = _read_npz(npz, path)
    for key in ("t", "q", "u"):
        if key not in arrays:
            raise RecordingInputError(f"RECORDING {path}: timeseries.npz has no {key!r}")
    t, q, u = arrays["t"], arrays["q"], arrays["u"]
    sysm = model.system
    meas = path / "measurements.npz"
    if q.shape[1] != sysm.n and not meas.is_file():
        raise RecordingInputError(
            f"RECORDING {path}: q has {q.shape[1]} columns, the scenario's robot {sysm.n}"
        )
    added = _added(path / "experiment.toml")
    truth = {}
    tf = path / "truth.toml"
    if tf.is_file():
        truth = tomllib.loads(tf.read_text()).get("parameters", {})
    pixels = None
    if meas.is_file():
        m = _read_npz(meas, path)
        t = m["t"]
        u = m["u"]
        tip = pose7_to_matrix(m["tip_pose"]) if "tip_pose" in m else None
        drone = pose7_to_matrix(m["drone_pose"]) if "drone_pose" in m else None
        pixels = m.get("pixels")
        # the true states, when in the scenario's coordinates (a synthetic recording of a
        # hidden robot with a richer strain basis has its own); never used by the fit
        q = q[: len(t)] if q.shape[1] == sysm.n else None
    else:
        if u.shape[0] == len(t) - 1:  # a run folder's u may miss the last sample
            u = np.vstack([u, u[-1:]])
        base, tipg = model.poses(sysm, q)
        tip = tipg
        drone = base if sysm.floating else None
    return Recording(
        path.name, t, u, model, tip, drone if sysm.floating else None, pixels,
        world.scene.target_points_world(), world.robot.local_camera, truth, q, added,
    )  # fmt: skip


def _read_npz(npz: Path, path: Path) -> dict:
    """The arrays of ``npz`` (of the recording ``path``), or one-line error if it cannot be
    read (truncated, or not an ``.npz``)."""
    try:
        with np.load(npz) as d:
            return {k: d[k] for k in d.files}
    except (OSError, EOFError, ValueError, zipfile.BadZipFile) as exc:
        raise RecordingInputError(
            f"RECORDING {path}: {npz.name} cannot be read ({npz_problem(exc)})"
        ) from None


def _added(path: Path) -> dict:
    """The ``[added]`` table of an experiment file (known additions, e.g. a clip-on mass)."""
    if not path.is_file():
        return {}
    table = tomllib.loads(path.read_text()).get("added", {})
    from .params import PARAMETERS

    for k in table:
        if k not in PARAMETERS:
            raise RecordingInputError(f"{path}: [added] {k!r} is not a parameter")
    return {k: float(v) for k, v in table.items()}


def _load_mcap(path: Path, scenario, topic_map) -> Recording:
    from ..recording import pose_matrices, read_mcap

    model, world = model_of_scenario(_scenario_for(path, scenario))
    sysm = model.system
    sig = read_mcap(path, topic_map, t0="first")
    if "tip_pose" not in sig:
        raise RecordingInputError(f"RECORDING {path}: the topic map gives no 'tip_pose' signal")
    if "tensions" not in sig:
        raise RecordingInputError(f"RECORDING {path}: the topic map gives no 'tensions' signal")
    tip_s = sig["tip_pose"]
    t = np.asarray(tip_s.t, float)
    t = t[0] + np.arange(len(t)) * np.median(np.diff(t))  # the mocap clock, made uniform
    tip = pose_matrices(tip_s)
    cols = [_hold(sig["tensions"], t)]
    drone = None
    if sysm.floating:
        for need in ("thrusts", "drone_pose"):
            if need not in sig:
                raise RecordingInputError(
                    f"RECORDING {path}: a flying base needs a {need!r} signal in the topic map"
                )
        cols.insert(0, _hold(sig["thrusts"], t))
        dp = sig["drone_pose"]
        drone = _interp_poses(np.asarray(dp.t, float), pose_matrices(dp), t)
    u = np.hstack(cols)
    added = _added(path.with_suffix(".experiment.toml"))
    return Recording(
        path.stem, t, u, model, tip, drone, None, world.scene.target_points_world(),
        world.robot.local_camera, added=added,
    )  # fmt: skip


def _hold(signal, t: np.ndarray) -> np.ndarray:
    """The last value at or before every ``t`` (a zero-order hold; the first before it)."""
    ts = np.asarray(signal.t, float)
    v = np.asarray(signal.values, float).reshape(len(ts), -1)
    k = np.clip(np.searchsorted(ts, t + 1e-9, side="right") - 1, 0, len(ts) - 1)
    return v[k]


def _interp_poses(ts, g, t):
    """Poses at ``t``: positions interpolated linearly, rotations by slerp."""
    from scipy.spatial.transform import Slerp

    tt = np.clip(t, ts[0], ts[-1])
    out = np.tile(np.eye(4), (len(t), 1, 1))
    for i in range(3):
        out[:, i, 3] = np.interp(tt, ts, g[:, i, 3])
    out[:, :3, :3] = Slerp(ts, Rotation.from_matrix(g[:, :3, :3]))(tt).as_matrix()
    return out

"""The small, explicit data that flows between the blocks of the closed loop.

One control period moves data one way (paper, "Simulation Results" and Fig. 2):

    PlantState --Sensors--> SensorReadings --Estimation--> StateEstimate
    SensorReadings --Perception--> LocalView / GlobalView
    (LocalView, GlobalView, StateEstimate) --Servo--> ServoCommand
    (StateEstimate, ServoCommand) --LowLevel--> ActuatorCommand --Plant--> PlantState

Every record is a frozen dataclass of plain numpy arrays and numbers; no block keeps a
reference to another block's internals. Only :class:`PlantState` carries the true state: the
sensors read it, the logger records it, nothing downstream of the sensors sees it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from ..estimation.estimate import StateEstimate  # noqa: F401  (shared with the estimator)
from ..vision.detect import NOT_DETECTED, Detection


class Termination(StrEnum):
    """Why a run, a campaign run or an env episode ended before its duration (the summary's
    ``termination``; its ``termination_reason`` says it in words, with the numbers)."""

    SAFETY = "safety"  # the error-growth monitor (paper, "Simulation Results")
    RECOVERY_FAILED = "recovery failed"  # no C_G view of the target, or planning failed
    PLANT_FAILED = "plant failed"  # the plant's integration failed (singular mass matrix)
    INTERRUPTED = "interrupted"  # Ctrl-C
    BEHIND_CAMERA = "behind camera"  # a detected point maps behind the virtual camera C_V
    TARGET_LOST = "target lost"  # env: the target not detected for max_lost periods
    OUT_OF_ENVELOPE = "out of envelope"  # env: roll/pitch beyond its limit or a non-finite state
    SUCCESS = "success"  # env: the image error fell below the success threshold
    FORCE_LIMIT = "force limit"  # the obstacles pushed on the arm harder than the limit
    TUMBLED = "tumbled"  # the drone's roll or pitch beyond plant.MAX_TILT_RAD
    ESTIMATOR_FAILED = "estimator failed"  # the filter diverged (non-finite or singular model)
    NON_FINITE = "non-finite command"  # a twist or actuator command with NaN or inf
    CONTROLLER_FAILED = "controller failed"  # the low-level controller raised or its output
    # was malformed (not an ActuatorCommand, or u not n_u numbers)


@dataclass(frozen=True)
class ControllerFailure:
    """Why the low-level controller ended a run (:attr:`Termination.CONTROLLER_FAILED`):
    ``error`` in words, naming the controller; when it raised, the innermost frame of the
    controller's own code (``file``, ``line``, ``function`` and that line's ``code``)."""

    error: str
    file: str | None = None
    line: int | None = None
    function: str | None = None
    code: str | None = None

    def where(self) -> str | None:
        """The frame as a traceback prints it (``File "...", line N, in f``), or ``None``."""
        if self.file is None:
            return None
        return f'File "{self.file}", line {self.line}, in {self.function}'


#: The phases of servoing into contact (:mod:`tdacm.loop.touch`), in order (logged as their
#: index, ``touch_phase``).
PHASES = ("approach", "contact", "hold", "release")


class ServoEvent(StrEnum):
    """A change of the servo's mode in one period (:attr:`ServoCommand.event`)."""

    IBVS_ENGAGED = "ibvs engaged"
    TARGET_LOST = "target lost"


@dataclass(frozen=True)
class PlantState:
    """The simulated robot's true state at time ``t`` (read by sensors and the logger only).
    ``qdd``: the accelerations at ``t`` under the input held over the period that ended at
    ``t`` (what an accelerometer senses; computed only when a sensor needs it, else ``None``)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray | None = None


@dataclass(frozen=True)
class CameraMeasurement:
    """What a camera delivers for one period: a detection (pixels in the paper's corner order,
    with the imperfection models applied) captured at ``t_capture`` (earlier than now when the
    camera has latency). ``image`` is kept only when asked for (video, snapshots)."""

    t_capture: float
    detection: Detection = NOT_DETECTED
    image: np.ndarray | None = None

    @property
    def found(self) -> bool:
        return self.detection.found


NO_MEASUREMENT = CameraMeasurement(float("nan"))


class DeferredMeasurement:
    """A camera measurement offered for one period but taken only when read: ``take`` (an
    argument-free callable, e.g. the sensor's ``measure`` bound to this period's state) runs on
    the first access to :attr:`detection`, :attr:`image` or :attr:`found`, then its result is
    kept. C_G is offered every ``cameras.global_every`` periods, but rendering it (PyBullet,
    ~70 ms) is paid only when the servo looks (a recovery snapshot) or an output asks for it.
    The camera's measurement depends on the period's state only (no noise drawn, no tracking),
    so taking it late gives the frame an eager read would have given."""

    __slots__ = ("t_capture", "_take", "_value")

    def __init__(self, t_capture: float, take):
        self.t_capture = float(t_capture)
        self._take = take
        self._value: CameraMeasurement | None = None

    @property
    def taken(self) -> bool:
        """Whether the measurement was made (the camera rendered this period)."""
        return self._value is not None

    def value(self) -> CameraMeasurement:
        if self._value is None:
            self._value = self._take()
            self._take = None
        return self._value

    @property
    def detection(self) -> Detection:
        return self.value().detection

    @property
    def image(self) -> np.ndarray | None:
        return self.value().image

    @property
    def found(self) -> bool:
        return self.value().found


@dataclass(frozen=True)
class SensorReadings:
    """Everything the sensors produced in one period. ``global_`` is the C_G measurement
    offered to the servo (on its request, or every ``cameras.global_every`` periods; ``None``
    otherwise), a :class:`DeferredMeasurement` rendered only if read. ``global_output`` is the
    C_G frame rendered for the outputs (every ``cameras.global_output_every`` periods, or every
    period for a video; ``None`` otherwise). ``other`` holds the measurements of further
    sensors by name (drone pose, IMU, encoders)."""

    t: float
    local: CameraMeasurement
    global_: CameraMeasurement | DeferredMeasurement | None = None
    other: dict = field(default_factory=dict)
    global_output: CameraMeasurement | None = None

    @property
    def global_rendered(self) -> CameraMeasurement | None:
        """The C_G frame rendered this period, for whatever consumer (``None``: not rendered)."""
        if self.global_output is not None:
            return self.global_output
        g = self.global_
        if isinstance(g, DeferredMeasurement):
            return g.value() if g.taken else None
        return g


@dataclass(frozen=True)
class LocalView:
    """Perception of C_L: the target's four points in normalized coordinates of C_L (with the
    controller's intrinsics) and their depths from the known target geometry (planar PnP).
    ``pixels`` are the detected pixels (for the mode switch and the logs)."""

    t_capture: float
    found: bool = False
    pixels: np.ndarray | None = None
    points: np.ndarray | None = None
    depths: np.ndarray | None = None


NOT_SEEN = LocalView(float("nan"))


@dataclass(frozen=True)
class ForceReading:
    """The tip force estimate of one period: ``force`` (N) along ``normal`` (unit, inertial:
    the direction the surface pushes the probe, minus the camera's optical axis), its standard
    deviation ``sigma`` (N; from the inputs and the state covariance), ``valid`` False before
    the first applied input."""

    t: float
    force: float = float("nan")
    sigma: float = float("nan")
    normal: np.ndarray | None = None
    valid: bool = False


class GlobalView:
    """Perception of C_G: the detection the recovery planner needs (target pose by IPPE).
    ``detection`` may be a :class:`DeferredMeasurement` (:meth:`deferred`): then C_G renders
    only if the servo reads the view."""

    __slots__ = ("t_capture", "_detection", "_source")

    def __init__(self, t_capture: float, detection: Detection = NOT_DETECTED):
        self.t_capture = float(t_capture)
        self._detection = detection
        self._source = None

    @classmethod
    def deferred(cls, m: DeferredMeasurement) -> GlobalView:
        view = cls(m.t_capture, None)
        view._source = m
        return view

    @property
    def detection(self) -> Detection:
        if self._detection is None:
            self._detection = self._source.detection
        return self._detection

    @property
    def found(self) -> bool:
        return bool(self.detection.found or self.detection.corners)


@dataclass(frozen=True)
class ServoCommand:
    """The servo's output: the joint reference for the low-level controller, and what the
    servo computed on the way (logged). ``request_global`` asks the sensors for a C_G frame in
    the next period (the recovery planner needs one snapshot)."""

    mode: str
    q_d: np.ndarray
    qd_d: np.ndarray
    qdd_d: np.ndarray
    twist: np.ndarray  # [w; v] of C_V (C_L for a fixed base); zeros when not servoing
    features: np.ndarray | None = None
    error: np.ndarray | None = None
    points: np.ndarray | None = None  # normalized points in C_V (C_L for a fixed base)
    rmse: float = float("nan")  # normalized-point RMSE to the reference snapshot
    request_global: bool = False
    event: str | None = None  # e.g. "ibvs engaged", "recovery planned"
    plan: dict | None = None  # the recovery plan, when one was made this period
    failure: str | None = None  # set when the servo cannot go on (the run ends)
    rmse_measured: float = float("nan")  # RMSE of this period's measured points (if any)
    target_pose: np.ndarray | None = None  # the servo's estimate of the target (world)
    phase: str | None = None  # servoing into contact: the phase (tdacm.loop.touch.PHASES)
    phase_changed: bool = False  # ... entered this period (the safety monitor re-arms)
    tare_force: bool = False  # ask the tip force block to tare (contact-free) this period
    landing: int = 0  # servoing into contact: landings so far (0 before the first touch)
    arms: tuple | None = None  # several arms: one ArmServoState per arm (tdacm.loop.arms)


@dataclass(frozen=True)
class ActuatorCommand:
    """The real inputs ``u = [thrusts (4), tensions (n_a)]`` (tensions only for a fixed base)
    and the controller's internals worth logging."""

    u: np.ndarray
    tau: np.ndarray
    q_ref: np.ndarray
    V: float = float("nan")
    delta_hat: np.ndarray | None = None
    thrust_saturated: bool = False
    tension_saturated: bool = False

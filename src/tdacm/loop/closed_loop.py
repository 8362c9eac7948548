"""The closed loop: the blocks stepped in order at the control period (paper, Fig. 2).

One period of :meth:`ClosedLoop.step`, data flowing one way::

    readings = sensors.read(plant.state)               # C_L (+ C_G when due or requested)
    estimate = estimator.step(readings, u_prev, dt)    # q_hat, qdot_hat (true state: a pass-through)
    view     = perception.local(readings.local)        # normalized points + depths
    command  = servo.step(t, dt, view, global_view, estimate)   # IBVS / recovery -> q_d, qd_d
    act      = controller.step(estimate, command, dt)  # adaptive law -> thrusts, tensions
    logger.record(...); safety check
    plant.advance(act.u, dt)                           # true model, disturbances

A run ends at its duration or with a :class:`~.data.Termination` (``LoopStep.termination``,
with the reason in words): the safety monitor, a failed recovery, the plant's integration
failing, the drone tumbling, a detected point behind the virtual camera, the estimator
diverging, a non-finite command, the low-level controller raising or returning a malformed
command (:attr:`~.data.Termination.CONTROLLER_FAILED`, its frame in
:attr:`ClosedLoop.controller_failure`: the boundary with a user's code), or Ctrl-C. Whatever
state the plant, cameras, estimator or servo reach ends the run this way; an exception means a
bug. A C_L frame whose corners admit no pose with the target in front of the camera (large
pixel noise) is a missed frame, not an end.

``tdacm run``, campaigns and the Gymnasium env all drive this class
(:func:`tdacm.sim.assemble.build_loop` assembles it from a scenario).
"""

from __future__ import annotations

import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..control import Mode
from ..vision.virtual import BehindVirtualCamera
from .data import (
    ActuatorCommand,
    ControllerFailure,
    ForceReading,
    GlobalView,
    LocalView,
    SensorReadings,
    ServoCommand,
    ServoEvent,
    StateEstimate,
    Termination,
)
from .estimation import TrueState
from .logger import RunLog
from .safety import SafetyMonitor


@dataclass(frozen=True)
class LoopStep:
    """What one period produced (the env and the tests read it)."""

    t: float
    view: LocalView
    estimate: StateEstimate
    command: ServoCommand
    actuation: ActuatorCommand
    done: bool
    reason: str | None  # why it ended, in words (None: not ended, or ended at its duration)
    termination: Termination | None = None


@dataclass(frozen=True)
class Sensed:
    """The first half of a period (:meth:`ClosedLoop.sense`)."""

    readings: SensorReadings
    estimate: StateEstimate
    view: LocalView
    global_view: GlobalView | None
    force: ForceReading | None = None  # when the loop has a force block (servoing into contact)


@dataclass
class RunResult:
    """A finished (or interrupted) run: the log arrays, the events and why it ended."""

    arrays: dict
    frames: list
    terminated: bool
    reason: str | None
    wall_time_s: float
    switch_time: float | None
    plan: dict | None
    interrupted: bool = False
    termination: Termination | None = None
    controller_failure: ControllerFailure | None = None


class ClosedLoop:
    """The TD-ACM's closed loop made of blocks (module docstring).

    Parameters
    ----------
    plant, sensors, perception, servo, controller:
        The blocks (:class:`~.plant.Plant`, :class:`~.sensors.Sensors`,
        :class:`~.perception.Perception`, a :class:`~.protocols.Servo`, a
        :class:`~.protocols.LowLevelController`).
    dt:
        Control period (s).
    estimator:
        A :class:`~.protocols.Estimator` (default: the true state).
    safety:
        The paper's error-growth monitor (default: on, paper values).
    log:
        A :class:`~.logger.RunLog` (default: one on the servo's reference snapshot).
    force:
        A :class:`~.touch.TipForceBlock` (servoing into contact): its estimate goes to the
        servo's ``step`` as ``force=`` and to the log; ``None``: none.
    """

    def __init__(
        self,
        plant,
        sensors,
        perception,
        servo,
        controller,
        dt: float,
        estimator=None,
        safety: SafetyMonitor | None = None,
        log: RunLog | None = None,
        name: str = "",
        force=None,
    ):
        self.plant = plant
        self.sensors = sensors
        self.perception = perception
        self.servo = servo
        self.controller = controller
        self.dt = float(dt)
        self.estimator = estimator if estimator is not None else TrueState(plant)
        self.safety = safety if safety is not None else SafetyMonitor()
        self.log = log if log is not None else RunLog(servo.desired_points)
        self.name = name
        self.force = force
        self._u = None
        self._request_global = False
        self.switch_time = None
        self.plan = None
        #: why the low-level controller ended the run (it raised, or returned a malformed
        #: command), with its own frame; ``None`` while it works
        self.controller_failure: ControllerFailure | None = None

    # ------------------------------------------------------------------ run control
    def reset(self, q0=None, qd0=None) -> StateEstimate:
        """Start a run at ``(q0, qd0)`` at t = 0: without ``q0``, the plant's initial state
        (:attr:`.plant.Plant.initial`); without ``qd0``, at rest. Every block starts over, so
        :meth:`run` twice gives the same run twice when nothing random is drawn (sensor noise,
        disturbances and the like go on with their random streams)."""
        p = self.plant
        p.reset(q0, qd0)
        self.sensors.reset()
        self.perception.reset()
        self.safety.reset()
        est = self.estimator.reset(p.state.t)
        if self.force is not None:
            self.force.reset()
        # the initial mode from the first C_L view (an ideal look, no noise drawn)
        first = self.perception.local(self.sensors.first_look(p.state.t, p.state.q))
        self.servo.reset(est.q, first)
        self.controller_failure = None
        try:
            self.controller.reset(est)
        except Exception as exc:  # a user's controller: the first period ends the run
            if caused_by_interrupt(exc):
                raise
            self.controller_failure = _raised(exc, self.controller, "reset")
        self._u = None
        self._request_global = self.servo.mode == Mode.RECOVERY
        self.switch_time = None
        self.plan = None
        self.log.rows = {k: [] for k in self.log.rows}
        self.log.frames = []
        return est

    def sense(self) -> Sensed:
        """The first half of a period: sensors, estimation, perception at the current state."""
        readings = self.sensors.read(self.plant.state, self._request_global)
        est = self.estimator.step(readings, self._u, self.dt)
        view = self.perception.local(readings.local)
        gview = self.perception.global_(readings.global_)
        if self.force is None:
            return Sensed(readings, est, view, gview)
        return Sensed(readings, est, view, gview, self.force.step(est, self._u, self.dt))

    def act(self, sensed: Sensed, twist=None, u=None, last: bool = False) -> LoopStep:
        """The second half: servo, low-level control, logging, safety, plant. ``twist``
        replaces the IBVS twist and ``u`` the controller's output (external commands, e.g. the
        Gymnasium env's actions); ``last`` records the period without advancing the plant."""
        dt = self.dt
        plant = self.plant
        state = plant.state
        t = state.t
        est, view = sensed.estimate, sensed.view
        if est.failure is not None or not _finite(est.q, est.qd):
            reason = est.failure or "estimator gave a non-finite state"
            cmd = _stopped(self.servo.mode, est)
            return LoopStep(t, view, est, cmd, _hold(est), True, reason,
                            Termination.ESTIMATOR_FAILED)  # fmt: skip
        if twist is not None and not _finite(np.asarray(twist, float)):
            cmd = _stopped(self.servo.mode, est)
            return LoopStep(t, view, est, cmd, _hold(est), True,
                            "non-finite twist command", Termination.NON_FINITE)  # fmt: skip
        try:
            if sensed.force is None:
                cmd = self.servo.step(t, dt, view, sensed.global_view, est, twist)
            else:
                cmd = self.servo.step(t, dt, view, sensed.global_view, est, twist,
                                      force=sensed.force)  # fmt: skip
        except BehindVirtualCamera as exc:  # eq. (18) undefined: the run ends, as an outcome
            return LoopStep(t, view, est, _stopped(self.servo.mode, est), _hold(est), True,
                            f"servo: {exc}", Termination.BEHIND_CAMERA)  # fmt: skip
        self._request_global = cmd.request_global
        if cmd.event == ServoEvent.IBVS_ENGAGED:
            if self.switch_time is None:
                self.switch_time = t
            self.safety.arm(t)
        if cmd.phase_changed:  # servoing into contact: a new phase, a new reference view
            self.safety.arm(t)
        if cmd.tare_force and self.force is not None:
            self.force.tare()
        if cmd.plan is not None:
            self.plan = cmd.plan
        if cmd.failure is not None:
            return LoopStep(
                t, view, est, cmd, _hold(est), True, cmd.failure, Termination.RECOVERY_FAILED
            )
        if u is None:
            if self.controller_failure is None:
                act = self._control(est, cmd, dt)
            if self.controller_failure is not None:
                return LoopStep(t, view, est, cmd, _hold(est), True,
                                self.controller_failure.error,
                                Termination.CONTROLLER_FAILED)  # fmt: skip
        else:
            act = ActuatorCommand(np.asarray(u, float), np.zeros(len(est.q)), cmd.q_d)
        if not _finite(act.u):
            reason = "non-finite actuator command u" if u is not None else NON_FINITE_REASON
            return LoopStep(t, view, est, cmd, act, True, reason,
                            Termination.NON_FINITE)  # fmt: skip
        self.log.record(state, sensed.readings, view, est, cmd, act, sensed.force)
        self._u = act.u
        if cmd.mode == Mode.IBVS and not self.safety.check(t, cmd.rmse):
            return LoopStep(t, view, est, cmd, act, True, self.safety.reason, Termination.SAFETY)
        if last:
            return LoopStep(t, view, est, cmd, act, True, None)
        plant.advance(act.u, dt)
        if not plant.ok:
            return LoopStep(t, view, est, cmd, act, True, PLANT_FAILED_REASON,
                            Termination.PLANT_FAILED)  # fmt: skip
        if plant.tumbled:
            reason = tumbled_reason(plant.state.q, plant.state.t)
            return LoopStep(t, view, est, cmd, act, True, reason, Termination.TUMBLED)
        if getattr(plant, "over_limit", None) is not None:
            return LoopStep(t, view, est, cmd, act, True, plant.over_limit, Termination.FORCE_LIMIT)
        return LoopStep(t, view, est, cmd, act, False, None)

    def _control(self, est: StateEstimate, cmd: ServoCommand, dt: float):
        """The controller's command, checked (the boundary with a user's code): an exception
        or a malformed command sets :attr:`controller_failure` and returns ``None``."""
        try:
            act = self.controller.step(est, cmd, dt)
        except Exception as exc:
            if caused_by_interrupt(exc):  # Ctrl-C inside a kernel: the run's to handle
                raise
            self.controller_failure = _raised(exc, self.controller, "step")
            return None
        act, problem = checked_actuation(act, self.plant.system.n_u, len(est.q))
        if problem is None and _finite(act.u):  # non-finite: its own outcome (NON_FINITE)
            problem = out_of_range(act.u, self.plant.system)
        if problem is not None:
            self.controller_failure = ControllerFailure(
                f"controller {controller_name(self.controller)} {problem}"
            )
        return act

    def step(self, twist=None, u=None, last: bool = False) -> LoopStep:
        """One control period: :meth:`sense` then :meth:`act`."""
        return self.act(self.sense(), twist, u, last)

    def run(self, duration: float, progress: bool = False, on_step=None) -> RunResult:
        """Reset, then step until ``duration`` (``round(duration / dt) + 1`` samples) or a
        termination. Ctrl-C ends the run early with what was simulated so far
        (``interrupted``); the caller writes it and re-raises.

        ``on_step``: an observer called with each period's :class:`LoopStep` after the period
        (the last one too), e.g. :class:`tdacm.live.LiveRun` (publish the run as it goes) or
        :class:`tdacm.live.RealTime` (pace it to the wall clock). It may read the loop (its
        log, the plant's state) and take time; it must not change them, so the run is the same
        with or without it. Its time counts in ``wall_time_s``."""
        if (
            isinstance(duration, bool)
            or not isinstance(duration, int | float | np.integer | np.floating)
            or not np.isfinite(duration)
            or duration <= 0
        ):
            raise ValueError(
                f"duration must be a finite positive number of seconds, got {duration!r}"
            )
        nsteps = int(round(duration / self.dt))
        self.reset()
        bar = None
        if progress:
            from .._log import Progress

            bar = Progress(nsteps + 1, self.name or "run", "step")
        terminated, reason, interrupted, termination = False, None, False, None
        wall0 = time.perf_counter()
        try:
            for k in range(nsteps + 1):
                st = self.step(last=k == nsteps)
                if bar is not None:
                    bar.to(k + 1)
                if on_step is not None:
                    on_step(st)
                if st.done:
                    terminated, reason = st.reason is not None, st.reason
                    termination = st.termination
                    break
        except (KeyboardInterrupt, SystemError) as exc:
            # Ctrl-C inside a numba kernel arrives as a SystemError (possibly several nested)
            # caused by the interrupt
            if isinstance(exc, SystemError) and not caused_by_interrupt(exc):
                raise
            interrupted, terminated, reason = True, True, "interrupted (Ctrl-C)"
            termination = Termination.INTERRUPTED
        finally:
            if bar is not None:
                bar.close()
        wall = time.perf_counter() - wall0
        return RunResult(
            self.log.arrays(),
            self.log.frames,
            terminated,
            reason,
            wall,
            self.switch_time,
            self.plan,
            interrupted,
            termination,
            self.controller_failure if termination == Termination.CONTROLLER_FAILED else None,
        )

    def close(self) -> None:
        self.sensors.close()


#: why a run ends when the plant's integration fails (``Termination.PLANT_FAILED``)
PLANT_FAILED_REASON = "plant integration failed (singular mass matrix or non-finite state)"
#: why a run ends on a non-finite command of the low-level controller
NON_FINITE_REASON = "non-finite controller output u"


def tumbled_reason(q, t: float) -> str:
    """Why a run ends with the drone tumbled at ``q``, time ``t`` (``Termination.TUMBLED``)."""
    return (
        f"drone tumbled: roll {np.degrees(q[0]):.0f} deg, pitch {np.degrees(q[1]):.0f} deg "
        f"at t = {t:.2f} s"
    )


def caused_by_interrupt(exc: BaseException) -> bool:
    """True if a ``KeyboardInterrupt`` is anywhere in the exception's cause/context chain."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def controller_name(controller) -> str:
    """``module:Class`` of a controller (the ``controller.class`` that would build it)."""
    cls = type(controller)
    return f"{cls.__module__}:{cls.__qualname__}"


def _raised(exc: Exception, controller, method: str) -> ControllerFailure:
    """The failure of ``controller.method`` raising ``exc``: the message and the innermost
    frame of the controller's own package (else the innermost frame outside tdacm)."""
    frames = traceback.extract_tb(exc.__traceback__)
    ours = str(Path(__file__).resolve().parents[1])  # the tdacm package
    top = sys.modules.get(type(controller).__module__.split(".")[0])
    home = getattr(top, "__file__", None)
    home = str(Path(home).resolve().parent) if home else None

    def under(frame, folder):
        return folder is not None and str(Path(frame.filename).resolve()).startswith(folder)

    own = [f for f in frames if under(f, home)] or [f for f in frames if not under(f, ours)]
    frame = (own or frames or [None])[-1]
    text = str(exc).strip().splitlines()
    error = f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
    what = f"controller {controller_name(controller)} raised {error} in {method}"
    if frame is None:
        return ControllerFailure(what)
    return ControllerFailure(
        f"{what} ({frame.filename}:{frame.lineno})",
        frame.filename,
        frame.lineno,
        frame.name,
        (frame.line or "").strip() or None,
    )


def checked_actuation(act, n_u: int, n: int):
    """``(command, None)``: the controller's ``act`` with ``u`` of ``n_u`` and ``tau``,
    ``q_ref`` (and ``delta_hat`` if set) of ``n`` float entries; ``(None, what is wrong)``
    otherwise. A well-formed :class:`~.data.ActuatorCommand` is returned as it is."""
    try:
        u, tau, q_ref = act.u, act.tau, act.q_ref
    except AttributeError:
        return None, f"returned {type(act).__name__}, not an ActuatorCommand"
    dh = getattr(act, "delta_hat", None)
    fields = {"u": (u, n_u), "tau": (tau, n), "q_ref": (q_ref, n)}
    if dh is not None:
        fields["delta_hat"] = (dh, n)
    fixed = {}
    for name, (v, size) in fields.items():
        if type(v) is np.ndarray and v.dtype == np.float64 and v.shape == (size,):
            continue
        try:
            a = np.asarray(v, float)
        except (TypeError, ValueError):
            return None, f"returned {name} of type {type(v).__name__}, not {size} numbers"
        if a.shape != (size,):
            return None, f"returned {name} of shape {a.shape}, not ({size},)"
        fixed[name] = a
    try:
        V = float(getattr(act, "V", float("nan")))
        flags = [bool(getattr(act, k, False)) for k in ("thrust_saturated", "tension_saturated")]
    except (TypeError, ValueError) as exc:
        return None, f"returned a malformed V or saturation flag ({exc})"
    if not fixed and type(act) is ActuatorCommand:
        return act, None
    uu, tt, qq = (fixed.get(k, v) for k, v in (("u", u), ("tau", tau), ("q_ref", q_ref)))
    return ActuatorCommand(uu, tt, qq, V, fixed.get("delta_hat", dh), *flags), None


#: slack of the actuator range check (relative to the range): rounding in a controller's own
#: clipping or allocation is not a violation
RANGE_SLACK = 1e-6


def actuator_ranges(system) -> tuple[np.ndarray, list[str]]:
    """The upper bound of each input of ``system`` (``u = [thrusts, tensions]``, the lower
    bound 0: rotors push and tendons pull, never the other way; the docs' ``[0, max_thrust]``
    and ``[0, max_tension]``) and each input's name."""
    hi, names = [], []
    if system.floating:
        hi += [float(system.base.max_thrust)] * 4
        names += [f"thrust of rotor {i + 1}" for i in range(4)]
    several = len(system.arms) > 1
    for k, arm in enumerate(system.arms):
        t = arm.tendons
        hi += [float(t.max_tension)] * t.n
        names += [f"tension of {'arm ' + str(k) + ' ' if several else ''}tendon {i + 1}"
                  for i in range(t.n)]  # fmt: skip
    return np.asarray(hi), names


def out_of_range(u, system) -> str | None:
    """What of the command ``u`` lies outside the actuator ranges of ``system``
    (:func:`actuator_ranges`, with :data:`RANGE_SLACK`), or ``None``."""
    hi, names = actuator_ranges(system)
    if len(hi) != len(u):
        return None
    slack = RANGE_SLACK * hi
    bad = np.flatnonzero((u < -slack) | (u > hi + slack))
    if bad.size == 0:
        return None
    i = int(bad[0])
    return f"commanded u[{i}] = {u[i]:.4g} N ({names[i]}), outside its range [0, {hi[i]:g}] N" + (
        f" ({bad.size} inputs out of range)" if bad.size > 1 else ""
    )


def _finite(*arrays) -> bool:
    return all(bool(np.isfinite(a).all()) for a in arrays)


def _stopped(mode: str, est: StateEstimate) -> ServoCommand:
    """The command of a period that ended before the servo ran (nothing commanded)."""
    n = len(est.q)
    return ServoCommand(mode, np.array(est.q, float), np.zeros(n), np.zeros(n), np.zeros(6))


def _hold(est: StateEstimate) -> ActuatorCommand:
    n = len(est.q)
    return ActuatorCommand(np.zeros(0), np.zeros(n), est.q)

"""Closed-loop simulation of a scenario (paper, "Simulation Results").

The loop itself is :class:`tdacm.loop.ClosedLoop` (blocks: plant, sensors, estimation,
perception, servo, low-level control, safety, logger; see :mod:`tdacm.loop`). This module runs a
scenario through it and writes the run folder: :class:`Simulation` (one run, with its summary)
and :func:`run_scenario` (load, run, write).

Normalized RMSE: ``sqrt(mean_k |p_k - p_k^d|^2)`` over the four points in normalized image
coordinates (C_V for a floating base, C_L for a fixed one).
"""

from __future__ import annotations

import inspect
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._compiling import compiling
from ..lie.se3 import rotation_angle
from ..loop.ablation import TruthAblation
from ..loop.closed_loop import ClosedLoop, controller_name
from ..loop.data import PHASES
from ..loop.safety import SafetyMonitor
from ..loop.sensors import RenderedFrontEnd
from ..loop.servo import MODE_CODES, normalized_rmse, target_estimate
from .assemble import Assembly, World, build_loop, camera_pose_error
from .outputs import write_run
from .scenario import Scenario, check_run, load_scenario

__all__ = [
    "MODE_CODES",
    "SUCCESS_RMSE",
    "SafetyMonitor",
    "Simulation",
    "normalized_rmse",
    "run_scenario",
]

#: The normalized RMSE at or below which a run counts as a success by default: a campaign's
#: ``success_rmse`` (:class:`~tdacm.campaign.spec.CampaignSpecConfig`) and the servoing task's
#: (:class:`~tdacm.envs.options.EnvOptions`).
SUCCESS_RMSE = 0.01


class Simulation:
    """One closed-loop run of a scenario; :meth:`run` returns the log arrays and the summary.

    ``controller``, ``servo`` and ``estimator`` replace the scenario's blocks (objects that
    implement the protocols of :mod:`tdacm.loop.protocols`). With ``video``, the cameras keep
    their images and ``frame_composer(readings, view, command, t)`` (e.g.
    :class:`tdacm.viz.video.CaptionedFrames`) turns each period into a frame; a composer with a
    ``bind(loop)`` method is bound to the built loop first. The frames are in
    ``self.result.frames`` after :meth:`run`."""

    def __init__(
        self,
        scenario: Scenario | str,
        duration=None,
        seed=None,
        video=False,
        progress=False,
        controller=None,
        servo=None,
        estimator=None,
        frame_composer=None,
    ):
        self.scenario = load_scenario(scenario) if isinstance(scenario, str) else scenario
        check_run(self.scenario, duration, seed, flags=False)  # ScenarioError naming the keyword
        cfg = self.scenario.config
        self.duration = float(cfg.duration if duration is None else duration)
        self.seed = int(cfg.seed if seed is None else seed)
        self.video = bool(video)
        self.progress = bool(progress)
        self.blocks = {"controller": controller, "servo": servo, "estimator": estimator}
        self.frame_composer = frame_composer if self.video else None
        self.assembly: Assembly | None = None
        self.result = None

    @property
    def loop(self) -> ClosedLoop | None:
        return None if self.assembly is None else self.assembly.loop

    @compiling("run")
    def build(self) -> Assembly:
        """Assemble the loop (:func:`~tdacm.sim.assemble.build_loop`; its checks raise
        :class:`~tdacm.sim.ScenarioError`). :meth:`run` builds it if this was not called."""
        composer = self.frame_composer
        self.assembly = build_loop(
            self.scenario, self.seed, video=self.video, frame_composer=composer, **self.blocks
        )
        if composer is not None and hasattr(composer, "bind"):
            composer.bind(self.assembly)
        return self.assembly

    @compiling("run")
    def run(self, out_dir=None, on_step=None):
        """Run; write the data of the run folder ``out_dir`` if given
        (:func:`~tdacm.sim.outputs.write_run`). Ctrl-C writes what was simulated so far, then
        re-raises ``KeyboardInterrupt``. ``on_step``: the loop's per-period observer
        (:meth:`tdacm.loop.ClosedLoop.run`; e.g. the live server's, :mod:`tdacm.live`)."""
        assembly = self.assembly if self.assembly is not None else self.build()
        loop = assembly.loop
        try:
            if out_dir is not None:
                write_scene_picture(Path(out_dir) / "scene.png", assembly)
            result = self.result = loop.run(self.duration, progress=self.progress, on_step=on_step)
            summary = self.summary(assembly, result)
            summary["interrupted"] = bool(result.interrupted)
            if out_dir is not None:
                write_run(
                    Path(out_dir),
                    result.arrays,
                    summary,
                    loop.servo.desired_points,
                    loop.plant.system,
                    scenario=self.scenario,
                )
        finally:
            loop.close()
        if result.interrupted:
            raise KeyboardInterrupt
        return result.arrays, summary

    def summary(self, assembly: Assembly, result) -> dict:
        """The run's summary (:func:`run_summary`) from the loop's result."""
        loop = assembly.loop
        return run_summary(
            assembly,
            result.arrays,
            RunOutcome(
                seed=self.seed,
                requested_duration=self.duration,
                wall_time_s=result.wall_time_s,
                terminated=bool(result.terminated),
                reason=result.reason,
                termination=result.termination,
                switch_time=result.switch_time,
                plan=result.plan,
                controller_failure=result.controller_failure,
                target_estimate=target_estimate(loop.servo),
                estimator_timings=getattr(loop.estimator, "timings", None),
            ),
        )


@dataclass(frozen=True)
class RunOutcome:
    """How a run went besides its arrays, for :func:`run_summary`: its seed, the duration
    asked for, its wall time, why it ended (``terminated``, ``reason``, ``termination``), when
    IBVS first engaged after a recovery (``switch_time``), the recovery's plan, the low-level
    controller's failure, the robust servo's final estimate of the target
    (``target_estimate``: ``(pose, covariance, rejected frames)`` or ``None``) and the
    estimator's step times (s, or ``None``)."""

    seed: int
    requested_duration: float
    wall_time_s: float
    terminated: bool
    reason: str | None
    termination: object
    switch_time: float | None
    plan: dict | None
    controller_failure: object = None
    target_estimate: tuple | None = None
    estimator_timings: object = None


def run_summary(assembly: Assembly, a: dict, outcome: RunOutcome) -> dict:
    """The summary of a run of ``assembly``'s scenario from its arrays ``a`` (the
    :class:`~tdacm.loop.logger.RunLog` arrays: ``t``, ``rmse``, ``mode``, ``q``, ``u``, the
    saturation flags, the detections; the others where the run has them) and ``outcome``:
    one summary for ``tdacm run``, the campaigns and the batched engine."""
    loop = assembly.loop
    s = loop.plant.system
    scenario = assembly.scenario
    rmse = a["rmse"]
    t = a["t"]
    finite = np.isfinite(rmse)
    initial = float(rmse[finite][0]) if finite.any() else None
    final = float(rmse[finite][-1]) if finite.any() else None

    def reach(level):
        idx = np.flatnonzero(finite & (rmse <= level))
        return float(t[idx[0]]) if idx.size else None

    # after convergence the RMSE wanders (docs/estimation.md, "What limits test C"): the last
    # sample alone (final_rmse) ranks runs noisily; late_rmse_1s is the windowed criterion
    last2 = last_samples(t, rmse, 2.0)

    u = a["u"]
    na = s.n_a
    sim_t = float(t[-1]) if t.size else 0.0
    q_star = assembly.world.q_star
    cam_dp = cam_da = drone_dp = None
    if t.size:
        cam_dp, cam_da = camera_pose_error(loop, a["q"][-1], q_star)
        if s.floating:
            drone_dp = float(np.linalg.norm(a["q"][-1][3:6] - q_star[3:6]))
    cfg = scenario.config
    wall = outcome.wall_time_s
    term = outcome.termination
    return {
        "scenario": scenario.name,
        "seed": outcome.seed,
        "duration": sim_t,
        "requested_duration": outcome.requested_duration,
        "dt": cfg.dt,
        "perturbation": cfg.model.perturbation,
        "initial_rmse": initial,
        "final_rmse": final,
        "min_rmse": float(np.nanmin(rmse)) if finite.any() else None,
        "late_rmse_1s": late_rmse(t, rmse, 1.0),
        "within_0.01_last_2s": float(np.mean(last2 <= 0.01)) if last2.size else None,
        "time_to_0.01": reach(0.01),
        "time_to_0.001": reach(0.001),
        "mode_switch_time": outcome.switch_time,
        "initial_mode": "recovery" if a["mode"].size and a["mode"][0] == 1 else "ibvs",
        "recovery_plan": outcome.plan,
        "terminated": bool(outcome.terminated),
        "termination_reason": outcome.reason,
        "termination": None if term is None else str(term),
        "final_camera_position_error_m": cam_dp,
        "final_camera_rotation_error_deg": cam_da,
        "final_drone_position_error_m": drone_dp,
        "wall_time_s": wall,
        "wall_per_sim_second": wall / sim_t if sim_t > 0 else None,
        "max_tension": float(u[:, -na:].max()) if u.size else 0.0,
        "min_tension": float(u[:, -na:].min()) if u.size else 0.0,
        "max_thrust": float(u[:, :4].max()) if (u.size and s.floating) else None,
        "tension_saturated_steps": int(np.sum(a["tension_saturated"])),
        "thrust_saturated_steps": int(np.sum(a["thrust_saturated"])),
        "final_q": a["q"][-1].tolist() if a["q"].size else None,
        "local_detection_rate": float(np.mean(a["detected_local"])) if t.size else 0.0,
        "profile": cfg.controller.profile,
        # an ablation (tdacm.loop.ablation): the controller read these from the plant
        "controller_truth": cfg.estimation.controller_truth or None,
        "controller": controller_provenance(loop.controller),
        "controller_failure": _failure(outcome.controller_failure),
        "final_rmse_true": _last_finite(a.get("rmse_true")),
        "final_rmse_measured": _last_finite(a.get("rmse_measured")),
        **arms_summary(a),
        **touch_summary(a, cfg),
        **_target_merit(outcome.target_estimate, assembly.world),
        **estimation_summary(a, s, cfg.estimation.source, outcome.estimator_timings),
    }


def controller_provenance(controller) -> dict:
    """How to get the low-level controller back: its ``class`` (``module:Class``, the
    ``controller.class`` that builds it), the ``file`` of its module and the ``version`` of its
    module or top-level package (``__version__``; ``None`` without one)."""
    if isinstance(controller, TruthAblation):
        controller = controller.controller
    cls = type(controller)
    try:
        file = inspect.getsourcefile(cls)
    except TypeError:  # defined interactively
        file = None
    module = cls.__module__
    version = None
    for name in (module, module.split(".")[0]):
        version = getattr(sys.modules.get(name), "__version__", None)
        if version is not None:
            break
    return {
        "class": controller_name(controller),
        "file": str(Path(file).resolve()) if file else None,
        "version": None if version is None else str(version),
    }


def _failure(failure) -> dict | None:
    """The summary's ``controller_failure``: the error and the controller's own frame."""
    if failure is None:
        return None
    return {
        "error": failure.error,
        "file": failure.file,
        "line": failure.line,
        "function": failure.function,
        "code": failure.code,
    }


def touch_summary(a: dict, cfg) -> dict:
    """Servoing into contact (``[touch]``, :mod:`tdacm.loop.touch`): the hold's figures from
    the log (empty without ``[touch] enabled``). ``hold_force_rms_rel``: RMS of the TRUE
    normal force minus the desired one over the hold, relative to the desired one;
    ``hold_image_error_max``: the task's image error over the hold, the largest normalized
    RMSE of the DETECTED C_L points to the reference snapshot in C_L (``rmse_local``,
    :func:`~tdacm.loop.touch.task_image_error`; periods without a detection skipped, ``None``
    if the hold has none); ``hold_image_error_true_max``: the same for the true C_L points;
    ``hold_image_error_servo_max``: the largest of the servo's own error (``rmse``: the
    predicted view in the camera it servoes, ``touch.contact_view``); ``hold_duration``: how
    long the hold lasted (s);
    ``max_contact_force``: the largest total contact force of the run (N). With several arms
    (a squeeze, :mod:`tdacm.loop.touch_arms`) every arm's force is judged over the hold (all
    arms holding) and the worst kept: ``hold_force_rms_rel`` is the largest of the arms'
    (``hold_force_rms_rel_arms``), the image error the largest over the arms,
    ``max_contact_force`` the largest force on one arm."""
    if "touch_phase" not in a:
        return {}
    tc = cfg.touch
    fd = float(tc.force)
    phase = a["touch_phase"]
    hold = phase == PHASES.index("hold")
    t = a["t"]
    dt = float(cfg.dt)
    out = {
        "touch_force": fd,
        "touch_hold_time": float(tc.hold_time),
        "touch_phase_reached": PHASES[int(phase.max())]
        if phase.size and phase.max() >= 0
        else None,
        "hold_duration": float(hold.sum() * dt),
        "landings": int(a["touch_landing"].max()) if "touch_landing" in a and t.size else 0,
        "hold_force_rms_rel": None,
        "hold_force_mean": None,
        "hold_force_max": None,
        "hold_force_estimate_error_max": None,
        "hold_force_estimate_error_rms": None,
        "hold_image_error_max": None,
        "hold_image_error_true_max": None,
        "hold_image_error_servo_max": None,
    }
    arms = "force_true_arms" in a  # several arms (a squeeze): every arm judged, the worst kept
    if hold.any():
        f = a["force_true_arms"][hold] if arms else a["force_true"][hold]
        fh = a["force_hat_arms"][hold] if arms else a["force_hat"][hold]
        rms = np.sqrt(np.mean((f - fd) ** 2, axis=0)) / fd
        out["hold_force_rms_rel"] = float(np.max(rms))
        if arms:
            out["hold_force_rms_rel_arms"] = [float(x) for x in rms]
        out["hold_force_mean"] = float(np.mean(f))
        out["hold_force_max"] = float(np.max(f))
        out["hold_force_estimate_error_max"] = float(np.nanmax(np.abs(fh - f)))
        out["hold_force_estimate_error_rms"] = float(np.sqrt(np.nanmean((fh - f) ** 2)))
        out["hold_image_error_max"] = _finite_max(a["rmse_local"][hold])
        out["hold_image_error_true_max"] = _finite_max(a["rmse_local_true"][hold])
        r = a["rmse"][hold]
        out["hold_image_error_servo_max"] = float(np.max(np.where(np.isfinite(r), r, np.inf)))
        if arms:
            out["hold_image_error_max_arms"] = [
                _finite_max(x) for x in np.asarray(a["rmse_local_arms"])[hold].T
            ]
    if arms and t.size:  # the force on each arm (the vector sum over the arms cancels)
        total = np.max(a["contact_force_arms"], axis=1)
        out["max_contact_force"] = float(total.max())
        rel = phase == PHASES.index("release")
        out["released"] = bool(rel.any() and total[rel][-1] == 0.0)
    elif "contact_tip" in a and t.size:
        total = np.linalg.norm(a["contact_tip"] + a["contact_rod"], axis=1)
        out["max_contact_force"] = float(total.max())
        rel = phase == PHASES.index("release")
        out["released"] = bool(rel.any() and total[rel][-1] == 0.0)
    return out


def _finite_max(x) -> float | None:
    """The largest finite value of ``x`` (``None`` if there is none)."""
    x = np.asarray(x, float)
    f = np.isfinite(x)
    return float(x[f].max()) if f.any() else None


def arms_summary(a: dict) -> dict:
    """Per-arm figures of a run with several arms (``[[robot.arms]]``; none for one arm): each
    arm's ``late_rmse_1s``, final RMSE and final true RMSE (the run's ``rmse`` series is the
    largest over the arms)."""
    if "rmse_arms" not in a:
        return {}
    t, r, rt = a["t"], np.asarray(a["rmse_arms"]), np.asarray(a["rmse_true_arms"])
    k = r.shape[1] if r.ndim == 2 else 0
    return {
        "late_rmse_1s_arms": [late_rmse(t, r[:, i], 1.0) for i in range(k)],
        "final_rmse_arms": [_last_finite(r[:, i]) for i in range(k)],
        "final_rmse_true_arms": [_last_finite(rt[:, i]) for i in range(k)],
    }


def last_samples(t, rmse, seconds):
    """The finite samples of ``rmse`` in the last ``seconds`` of the run."""
    finite = np.isfinite(rmse)
    return rmse[finite & (t >= t[-1] - seconds - 1e-9)] if t.size else rmse[:0]


def late_rmse(t, rmse, seconds: float = 1.0):
    """The RMS of the normalized feature RMSE over the last ``seconds`` of a run (its finite
    samples; ``None`` if there is none): the campaigns' windowed success criterion."""
    last = last_samples(np.asarray(t), np.asarray(rmse), seconds)
    return float(np.sqrt(np.mean(last**2))) if last.size else None


def _last_finite(x):
    if x is None:
        return None
    x = np.asarray(x, float)
    f = np.isfinite(x)
    return float(x[f][-1]) if f.any() else None


def _target_merit(estimate, world: World) -> dict:
    """Final error of the robust servo's target estimate (``(pose, covariance, rejected)``
    or ``None``, :func:`~tdacm.loop.servo.target_estimate`) and its own 1-sigma (worst
    rotation direction), when the servo has one."""
    if estimate is None:
        return {}
    pose, cov, rejected = estimate
    g_t = world.scene.target_pose
    e = np.linalg.solve(g_t, pose)
    ang = float(np.degrees(rotation_angle(e[:3, :3])))
    sig = float(np.degrees(np.sqrt(np.linalg.eigvalsh(cov[:3, :3]).max())))
    return {
        "final_target_estimate_error_m": float(np.linalg.norm(e[:3, 3])),
        "final_target_estimate_error_deg": ang,
        "final_target_estimate_sigma_deg": sig,
        "target_filter_rejected": int(rejected),
    }


#: Estimation errors are summarized after this time: the filter has converged by then
#: (strain RMS 3e-4 rad/m after 1 s, docs/estimation.md).
ESTIMATION_WINDOW_S = 1.0


def estimation_summary(a: dict, s, source: str, timings=None) -> dict:
    """RMS estimation errors after :data:`ESTIMATION_WINDOW_S` (all samples if the run is
    shorter): strains (per component, pooled; rad/m) and drone position (Euclidean; m);
    ``None`` for ``source = "true"``. Plus the filter's median cost per period."""
    out = {
        "estimation_source": source,
        "strain_estimation_rms": None,
        "drone_position_estimation_rms": None,
        "estimator_step_ms_median": None,
    }
    t = a["t"]
    if source != "estimated" or not t.size or "q_hat" not in a:
        return out
    win = t >= min(ESTIMATION_WINDOW_S, float(t[-1]))
    err = a["q_hat"][win] - a["q"][win]
    out["strain_estimation_rms"] = float(np.sqrt(np.mean(err[:, s.n - s.n_s :] ** 2)))
    if s.floating:
        out["drone_position_estimation_rms"] = float(
            np.sqrt(np.mean(np.sum(err[:, 3:6] ** 2, axis=1)))
        )
    if timings is not None and len(timings) > 1:
        out["estimator_step_ms_median"] = float(np.median(timings[1:]) * 1e3)
    return out


def write_scene_picture(path: Path, assembly: Assembly) -> None:
    """The scenario's geometry as the cameras see it: C_L at the start, C_L at the desired
    configuration (the reference snapshot), C_G at the start (arm drawn); with several arms,
    every arm's C_L (its marker) at the start and at the desired configuration."""
    import cv2

    loop, w = assembly.loop, assembly.world
    path.parent.mkdir(parents=True, exist_ok=True)
    tiles = []
    locals_ = getattr(loop.sensors, "locals_", None) or [loop.sensors.local]
    views = []
    for k, sensor in enumerate(locals_):
        arm = f" arm {k}" if len(locals_) > 1 else ""
        views += [(f"C_L{arm} initial", sensor, w.q0),
                  (f"C_L{arm} desired (reference)", sensor, w.q_star)]  # fmt: skip
    for label, sensor, q in (*views, ("C_G initial", loop.sensors.global_, w.q0)):
        if sensor is None or not isinstance(sensor.front_end, RenderedFrontEnd):
            continue
        img = sensor.front_end.render(sensor.pose(q), loop.plant.system, q)
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
        t = cv2.resize(
            np.ascontiguousarray(img[:, :, :3]), (500, 500), interpolation=cv2.INTER_AREA
        )
        cv2.putText(t, label, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 0), 2)
        tiles.append(t)
    for sensor in locals_:
        sensor.reset()
    if tiles:
        cv2.imwrite(str(path), cv2.cvtColor(np.concatenate(tiles, axis=1), cv2.COLOR_RGB2BGR))


def run_scenario(name, out=None, config=None, duration=None, seed=None, progress=False):
    """Load and run a scenario; returns ``(arrays, summary)`` and writes the data of the run
    folder ``out`` if given (figures: :func:`tdacm.viz.plot_run_dir`; both: ``tdacm run``)."""
    sc = load_scenario(name, config)
    check_run(sc, duration, seed, flags=False)  # reject nan/inf/<=0, seed < 0
    return Simulation(sc, duration=duration, seed=seed, progress=progress).run(out)

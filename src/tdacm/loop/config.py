"""Parameter records of the loop's blocks, one per scenario section they read: ``[ibvs]``,
``[servo]``, ``[recovery]``, ``[controller]``, ``[cameras]``, ``[safety]``, ``[disturbances]``
and the camera imperfections of ``[sensors]`` (:class:`SensorModel`); ``[model]`` is
:class:`tdacm.control.config.ModelConfig`, next to the controller's model.

Layout: a block's parameter record lives with its block (this module for the loop's blocks,
:mod:`tdacm.estimation.config` for the filter and the proprioceptive sensors), and the
scenario model of :mod:`tdacm.sim.config` composes them. So each default, range and
description is written once, next to the code that uses it, and imports only go down (the
loop never imports ``sim``). The blocks take these records whole (the servo its
:class:`IbvsConfig` and :class:`RecoveryConfig`, the touch servo its :class:`TouchConfig`, the
safety monitor its :class:`SafetyConfig`).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import field_validator

from .._config import ConfigModel, Field
from .._validate import unit_vector
from ..control.config import ControlLawConfig
from ..vision.ibvs import DEFAULT_MODE, DEFAULT_SOLVER

Vec2 = Annotated[list[float], Field(min_length=2, max_length=2)]
Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Vec6 = Annotated[list[float], Field(min_length=6, max_length=6)]

#: RK4 steps of the plant per control period: the default of the scenario's ``substeps`` and of
#: :class:`~tdacm.loop.plant.Plant`
PLANT_SUBSTEPS = 4


class IbvsConfig(ConfigModel):
    """Section ``[ibvs]``: the image-based visual servo and its command shaping
    (docs/control.md)."""

    gain: float = Field(1.0, gt=0, description="IBVS gain lambda of v = -lambda J_img^-1 e, 1/s")
    mode: Literal["current", "desired", "mean"] = Field(
        DEFAULT_MODE, description="interaction matrix at the current, desired or mean features"
    )
    compensation: Literal["exact", "rotation", "approx"] = Field(
        "exact", description="form of the virtual-camera (roll/pitch) compensation, eq. (18)"
    )
    max_joint_rate: float = Field(
        0.4, gt=0, description="rad/s, limit of the commanded rod strain and yaw rates"
    )
    max_drone_speed: float = Field(
        0.3, gt=0, description="m/s, limit of the commanded horizontal drone speed"
    )
    max_vertical_speed: float = Field(
        1.0, gt=0, description="m/s, limit of the commanded vertical drone speed"
    )
    soft_start: float = Field(
        1.0, ge=0, description="s, time constant of the ramp after IBVS engages (0: off)"
    )
    rate_filter: float = Field(
        0.15, ge=0, description="s, time constant of the joint-rate command filter (0: off)"
    )
    accel_feedforward: bool = Field(
        True, description="feed qdd_d = d(qd_d)/dt of the filtered rate command forward"
    )
    reference_leak: float = Field(
        4.0, description="1/s, pull of q_d toward the estimated q (anti wind-up)"
    )
    features: Literal["predicted", "measured"] = Field(
        "predicted",
        description="'predicted': features from the target filter (robust servo); "
        "'measured': the detected points",
    )
    floor: float = Field(
        0.05, ge=0, description="singular-value floor of the J_img solve (0: plain inverse)"
    )
    solver: Literal["floor", "damped"] = Field(
        DEFAULT_SOLVER, description="well-conditioned solve: floored singular values or damped"
    )
    filter_pixel_sigma: float = Field(
        1.0, gt=0, description="px, corner noise assumed by the target filter"
    )
    filter_window: int = Field(
        250, ge=1, description="frames fused by the target filter (sliding window)"
    )
    filter_smoothing: float = Field(
        1.0, ge=0, description="s, smoothing of the target estimate used for prediction"
    )
    target_level_prior_deg: float = Field(
        0.5, ge=0, description="deg, the target filter's prior that the target lies level (0: none)"
    )
    target_level_normal: Vec3 = Field(
        [0.0, 0.0, -1.0],
        description="unit vector, the world direction the prior believes the target's z axis "
        "(into its surface) has: [0, 0, -1] for a target lying face up",
    )

    @field_validator("target_level_normal")
    @classmethod
    def _unit(cls, v):
        unit_vector("target_level_normal", v)
        return v


class ServoConfig(ConfigModel):
    """Section ``[servo]``: what gives the servo's twist (:mod:`tdacm.loop.policy`)."""

    policy: str | None = Field(
        None,
        description="a saved policy file (.npz, relative to the scenario file's folder or "
        "the current one) whose twist replaces the IBVS twist (unset: IBVS)",
    )

    @field_validator("policy")
    @classmethod
    def _path(cls, v):
        if v is not None and not v.strip():
            raise ValueError("must be a file path (or unset)")
        return v


class RecoveryConfig(ConfigModel):
    """Section ``[recovery]``: the mode switch and the recovery planner."""

    max_speed: float = Field(0.3, gt=0, description="rad/s, speed of the recovery trajectory")
    margin_px: float = Field(
        20.0, ge=0, description="px, image margin inside which the target counts as seen"
    )
    confirm: int = Field(2, ge=1, description="frames in view before IBVS engages")
    lose: int = Field(5, ge=1, description="frames out of view before recovery starts")
    lost_timeout: float = Field(
        1.0,
        gt=0,
        description="s, predicted features: recovery only after no detection for this long "
        "(or the predicted points leave C_L's image for `lose` frames)",
    )


class ControllerConfig(ControlLawConfig):
    """Section ``[controller]``: the low-level controller (the paper's adaptive law with the
    drone loop and allocation, whose keys come from
    :class:`~tdacm.control.config.ControlLawConfig`, or a user class)."""

    profile: Literal["default", "paper"] = Field(
        "default",
        description="'default': the robust servo; 'paper': the paper's literal choices "
        "(docs/control.md, 'Profiles')",
    )
    class_: str = Field(
        "",
        alias="class",
        description="'package.module:ClassName' of a user controller ('': the adaptive one); "
        "found on sys.path, the current folder and the scenario file's folder",
    )
    options: dict[str, Any] = Field(
        {}, description="any keys: passed to a user controller as context.options"
    )


class CamerasConfig(ConfigModel):
    """Section ``[cameras]``: how the cameras' images are made (intrinsics and mounts are in
    ``[robot.cameras.*]``)."""

    local_renderer: Literal["planar", "analytic"] = Field(
        "planar", description="C_L: 'planar' (rendered image + detector) or 'analytic' projection"
    )
    global_every: int = Field(
        1,
        ge=0,
        description="C_G frame offered to the servo every this many periods (0: only on its "
        "request); rendered only when the servo reads it (a recovery snapshot)",
    )
    global_output_every: int = Field(
        0,
        ge=0,
        description="C_G rendered for the outputs (the logged detected_global) every this many "
        "periods (0: only when the servo reads it; a video renders every period)",
    )
    global_renderer: Literal["pybullet", "planar"] = Field("pybullet", description="C_G renderer")
    global_backend: Literal["auto", "egl", "tiny"] = Field(
        "auto", description="PyBullet backend: 'auto' (EGL if available), 'egl', 'tiny'"
    )


class SafetyConfig(ConfigModel):
    """Section ``[safety]``: the monitor that stops a diverging run."""

    enabled: bool = Field(True, description="stop the run when the image error grows")
    growth_limit: float = Field(
        0.05, gt=0, description="relative growth of the image error that stops the run"
    )
    min_increase: float = Field(
        0.005,
        ge=0,
        description="absolute increase (normalized units) below which growth is ignored",
    )
    grace: float = Field(0.5, ge=0, description="s after IBVS engages before the monitor arms")


class DisturbancesConfig(ConfigModel):
    """Section ``[disturbances]``: external loads on the plant."""

    base_wrench_amplitude: Vec6 = Field(
        [0.0] * 6,
        description="N m, N: amplitude of the wrench a sin(2 pi f t) on the drone, body frame "
        "[moment; force]",
    )
    base_wrench_frequency: float = Field(0.0, ge=0, description="Hz, its frequency")
    downwash: Vec3 = Field(
        [0.0, 0.0, 0.0],
        description="N/m, the rotors' downwash on the rod: an inertial force density",
    )
    downwash_noise: float = Field(
        0.0, ge=0, description="N/m, std of the noise added to the downwash every control period"
    )


class SensorModel(ConfigModel):
    """The local camera's imperfections (camera keys of ``[sensors]``). All randomness comes
    from one generator seeded by the run's seed."""

    pixel_noise: float = Field(0.0, ge=0, description="px, std of the noise on detected points")
    dropout: float = Field(0.0, ge=0, lt=1, description="probability that a frame has no detection")
    latency_steps: int = Field(0, ge=0, description="control periods between image and use")
    intrinsics_error: float = Field(
        0.0, ge=0, lt=0.5, description="relative std of the controller's fx, fy, cx, cy"
    )

    @property
    def ideal(self) -> bool:
        return (
            self.pixel_noise == 0
            and self.dropout == 0
            and self.latency_steps == 0
            and self.intrinsics_error == 0
        )


class TouchConfig(ConfigModel):
    """Section ``[touch]``: servoing into contact (:class:`~tdacm.loop.touch.TouchServo`,
    docs/contact.md): IBVS to a standoff view, then along the camera's axis onto the target
    until the estimated force reaches ``detect_force``, an admittance law holding ``force``
    for ``hold_time``, then back to the standoff. The reference snapshot (``[desired] q``) is
    the view at the contact pose; once the probe has touched, the servo reads it in the tip
    camera C_L (``contact_view``)."""

    enabled: bool = Field(False, description="servo into contact (the phases below)")
    force: float = Field(0.3, gt=0, description="N, desired normal force of the hold")
    contact_view: Literal["local", "virtual"] = Field(
        "local",
        description="the camera the servo reads once the probe has touched (the rest of the "
        "contact phase and the hold): 'local': the tip camera C_L against the reference "
        "snapshot in C_L (the task: where the probe presses on the marker; the pinned law, "
        "docs/contact.md); 'virtual': the virtual camera C_V, as in free flight",
    )
    hold_time: float = Field(3.0, gt=0, description="s, how long the force is held")
    settle: float = Field(
        1.0, ge=0, description="s, from the first touch to the start of the hold (the impact)"
    )
    settle_band: float = Field(
        0.1,
        ge=0,
        description="relative: the hold starts once the filtered force estimate is within this "
        "share of force (settle s after the touch at the earliest) ...",
    )
    settle_wait: float = Field(
        1.0,
        ge=0,
        description="s, ... or this long after settle whatever it reads",
    )
    standoff: float = Field(
        0.1, gt=0, description="m, distance along the camera axis of the approach view"
    )
    start_rmse: float = Field(
        0.01, gt=0, description="normalized RMSE to the standoff view that ends the approach"
    )
    dwell: float = Field(0.5, ge=0, description="s, that RMSE held before moving in")
    approach_speed: float = Field(
        0.03, gt=0, description="m/s, speed along the camera axis toward the surface"
    )
    approach_gain: float = Field(
        1.0, gt=0, description="1/s, axial speed per metre left to the contact pose"
    )
    touch_speed: float = Field(
        0.01, gt=0, description="m/s, the least axial speed toward the surface (at contact)"
    )
    detect_force: float = Field(
        0.1, gt=0, description="N, estimated force that counts as the first touch"
    )
    land_rmse: float = Field(
        0.007,
        gt=0,
        description="normalized, the largest task image error (the detected C_L points' RMSE to "
        "the reference in C_L, low-pass filtered over land_filter) at which a landing is kept "
        "when the hold would start; above it the probe is lifted and lands again",
    )
    land_correction: bool = Field(
        False,
        description="aim each new landing off by the offset the lifted ones repeated (their "
        "detected C_L centroids; off: the landings' scatter is larger than what they repeat, "
        "docs/contact.md)",
    )
    land_filter: float = Field(
        0.2, ge=0, description="s, time constant of that task image error's low-pass filter"
    )
    max_landings: int = Field(
        4, ge=1, description="landings tried; the last one is held wherever it is (1: no lift)"
    )
    lift_time: float = Field(
        0.5, gt=0, description="s, a lift: away from the surface at approach_speed for this long"
    )
    unload_time: float = Field(
        3.0,
        gt=0,
        description="s, several arms: a landing off a marker has its desired force ramped "
        "toward zero at force / unload_time (the balance loop on) until it is down to "
        "detect_force, then every arm goes back to its standoff view",
    )
    force_gain: float = Field(
        0.03, ge=0, description="m per N, admittance: axial reference offset per force error"
    )
    force_integral: float = Field(
        0.6, ge=0, description="m per N s, admittance: integral of the force error in the offset"
    )
    force_filter: float = Field(
        0.1, ge=0, description="s, time constant of the force estimate's low-pass filter"
    )
    input_sigma: float = Field(
        0.02,
        gt=0,
        description="N, assumed std of each applied thrust and tension (the "
        "estimated force's sigma)",
    )
    force_estimator: Literal["momentum", "differenced"] = Field(
        "momentum",
        description="tip-force estimate: 'momentum' (the generalized-momentum observer, no "
        "accelerations) or 'differenced' (the balance with accelerations from differenced "
        "velocities)",
    )
    observer_gain: float = Field(
        10.0,
        gt=0,
        description="1/s, the momentum observer's gain K_o (a first-order lag of 1/K_o s on "
        "the force; K_o dt < 2)",
    )
    balance_gain: float = Field(
        0.01,
        ge=0,
        description="m per N, several arms: each arm's axial reference offset per N of its "
        "force below the arms' mean (the squeeze's balance loop, docs/contact.md)",
    )
    balance_damping: float = Field(
        4.0,
        ge=0,
        description="s, several arms: axial reference offset per m/s of the arms' "
        "differential axial velocity (damping of the balance mode)",
    )
    balance_filter: float = Field(
        0.3,
        ge=0,
        description="s, time constant of the low-pass filter of that velocity",
    )

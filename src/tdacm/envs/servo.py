"""Gymnasium environment of the TD-ACM servoing task (registered as ``tdacm/TipServo-v0``).

The env drives the same :class:`tdacm.loop.ClosedLoop` as ``tdacm run`` and the campaigns, so
every scenario option applies: the robot, the sensor imperfections, the disturbances, the
command shaping, the estimator. Each step is one control period (paper: 20 ms): the action is
applied through the loop's blocks, the plant advances, and the new C_L view is observed.

Cameras: unless ``overrides`` say otherwise, both cameras are the analytic front end (the
target's corners projected, no image: what the campaigns use; C_G is read only for a recovery
snapshot), so no renderer runs inside ``step`` and none is initialized in the process
(fork-safe under ``AsyncVectorEnv``). With PyBullet for C_G (``overrides``), a process forked
after its parent loaded EGL renders with PyBullet's TinyRenderer instead. The servo is the
scenario's (as shipped, the robust servo on the features its target filter predicts,
``ibvs.features = "predicted"``; ``"measured"``: the detected points): the observation holds
the features it works on, the twist action replaces its IBVS twist. ``render()`` draws C_L's
view with the planar renderer, created on the first call in the calling process.

Watching a policy act: ``render_mode="foxglove"`` starts a Foxglove WebSocket server
(:class:`tdacm.live.LiveServer`, the ``live`` extra; ``live="[HOST:]PORT"``, default
``127.0.0.1:8765``) and publishes each step as it happens, in the topics of ``tdacm run --live``
(docs/live.md); ``render()`` then returns ``None``. The server reads the env and never writes
to it: the episodes are the same with or without it.

Actions (``action_type``):

* ``"twist"`` (default): the virtual-camera twist ``[w; v]`` (angular first, in C_V, or in C_L
  for a fixed base), scaled by ``max_angular``/``max_linear`` from ``[-1, 1]^6``; it replaces
  the IBVS twist, then goes through the servo's mapping ``qdot_d = pinv(J_L^L) Ad v`` and its
  command shaping, and the scenario's low-level controller tracks the result. A robot of
  ``k`` arms (``[[robot.arms]]``) takes ``6 k`` values, arm 0's twist first, each in its own
  arm's C_V, mapped jointly (docs/control.md, "Two arms").
* ``"actuators"``: raw inputs in ``[0, 1]`` scaled to ``[0, max_thrust]`` per motor and
  ``[0, max_tension]`` per tendon (fixed base: tensions only); no controller.

Observation (float32, size ``15 + 2 n`` for a robot of ``n`` coordinates): the one of the
policy block, :func:`tdacm.loop.policy.observation` (its layout and scaling,
:data:`OBSERVATION_SCALES`): the feature error, the four points in C_V, the detection flag,
the state estimate's offset from ``q*`` and its velocity, scaled and clipped to
``[-OBS_CLIP, OBS_CLIP]``. A robot of ``k`` arms: ``15 k + 2 n``, the first 15 entries (error,
points, detection) per arm, arm 0 first, then the state once.

Reward per step: ``-rmse``, minus the normalized RMSE of the four points to the reference
snapshot (C_V; with several arms the largest of the arms', the target seen when every arm
sees its own); ``-lost_penalty`` when the target is not detected. Success (``rmse <=
success_rmse``) adds ``success_bonus`` and ends the episode. A failure ending (the target lost
for ``max_lost`` steps, the state out of its envelope, the loop's own termination) gives
``-lost_penalty`` for each step left until ``max_steps``, as if the target had stayed lost: a
failure never pays better than servoing badly. ``info["termination"]`` names why an episode
ended (:class:`tdacm.loop.data.Termination`; ``None`` while it runs and on truncation).

``reset`` reuses the assembled loop: the plant state, the blocks and the random streams are
reset; a ``seed`` draws the loop's seed from the env's generator and gives the loop the model
perturbation, sensor noise and disturbances of that seed (:func:`tdacm.sim.assemble.reseed`;
scenarios with an intrinsics error or the estimator are rebuilt instead).
"""

from __future__ import annotations

import math
import time

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .._records import take
from ..loop.data import Termination
from ..loop.policy import (
    ANGLE_SCALE,
    FEATURE_SCALE,
    OBS_CLIP,
    OBSERVATION_SCALES,
    POSITION_SCALE,
    STRAIN_SCALE,
    observation,
    observation_size,
    state_scales,
)
from ..loop.servo import BEHIND
from ..vision.virtual import BehindVirtualCamera
from .options import EnvOptions, clip_action

#: Observation scaling (module docstring), one definition with the policy block's
#: (:mod:`tdacm.loop.policy`).
__all__ = [
    "ANGLE_SCALE", "FEATURE_SCALE", "OBSERVATION_SCALES", "OBS_CLIP", "POSITION_SCALE",
    "STRAIN_SCALE", "TipServoEnv",
]  # fmt: skip

#: Roll/pitch (rad) beyond which the episode ends (Termination.OUT_OF_ENVELOPE).
MAX_TILT = 1.2
#: The env's scenario defaults (module docstring), under the user's overrides.
ENV_DEFAULTS = {
    "cameras": {"local_renderer": "analytic", "global_renderer": "planar"},
}


def _merge(a: dict, b: dict) -> dict:
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in a.items()}
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _perceive_once(perceive):
    """``perceive`` (a servo's bound ``perceive``) memoized on its last ``(view, est)``: the
    env's observation and the servo's step of the same period share one call (and its
    :class:`~tdacm.vision.virtual.BehindVirtualCamera`)."""
    memo = [None, None, None, None]

    def perceive_once(t, dt, view, est):
        if memo[0] is not view or memo[1] is not est:
            try:
                memo[:] = view, est, perceive(t, dt, view, est), None
            except BehindVirtualCamera as exc:
                memo[:] = view, est, None, exc
        if memo[3] is not None:
            raise memo[3]
        return memo[2]

    return perceive_once


class TipServoEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array", "foxglove"], "render_fps": 50}

    def __init__(
        self,
        options: EnvOptions | None = None,
        render_mode: str | None = None,
        live: str | int | None = None,
        **kwargs,
    ):
        """The task of ``options`` (an :class:`~tdacm.envs.options.EnvOptions`) with the
        keywords ``kwargs`` replacing some of its fields (its defaults otherwise).
        ``render_mode="foxglove"``: publish each step to a Foxglove client on ``live``
        (``"[HOST:]PORT"`` or a port; default ``127.0.0.1:8765``; module docstring)."""
        from ..sim.assemble import build_loop
        from ..sim.scenario import load_scenario

        o = self.options = EnvOptions.of(options, kwargs)
        o.randomize.refuse("the env")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(
                f"render_mode must be None, 'rgb_array' or 'foxglove', got {render_mode!r}"
            )
        if live is not None and render_mode != "foxglove":
            raise ValueError(f"live: a server address needs render_mode='foxglove', got {live!r}")
        self.live = None  # the Foxglove server (render_mode="foxglove")
        action_type = o.action_type
        sc = load_scenario(o.scenario)
        ov = _merge(ENV_DEFAULTS, o.overrides or {})
        if not o.safety:
            ov = _merge(ov, {"safety": {"enabled": False}})
        sc = sc.with_overrides(ov, "env overrides")
        if sc.config.servo.policy is not None:
            raise ValueError(
                "servo.policy: the env's action replaces the servo's twist; run a saved policy "
                "on the env's observation (tdacm.loop.policy.load_policy) or in the block loop"
            )
        self.scenario = sc
        self.action_type = action_type
        self.max_steps = int(o.max_steps)
        self.success_rmse = float(o.success_rmse)
        self.success_bonus = float(o.success_bonus)
        self.lost_penalty = float(o.lost_penalty)
        self.max_lost = int(o.max_lost)
        self.hold = bool(o.hold_success)
        self.render_mode = render_mode
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / sc.config.dt)))
        self._renderer = None
        self.assembly = build_loop(sc, int(sc.config.seed))
        self.loop, self.world = self.assembly.loop, self.assembly.world
        self._quiet_log()
        s = self.loop.plant.system
        self.n = n = s.n
        self.init_noise = o.initial_std(n)
        k = len(self._arm_servos)
        if action_type == "twist":
            self.action_space = spaces.Box(-1.0, 1.0, shape=(6 * k,), dtype=np.float32)
        else:
            self.action_space = spaces.Box(0.0, 1.0, shape=(s.n_u,), dtype=np.float32)
            self._top = np.r_[
                np.full(4, s.base.max_thrust) if s.floating else [],
                np.full(s.n_a, s.tendons.max_tension),
            ]
        self.scale = np.tile([o.max_angular] * 3 + [o.max_linear] * 3, k).astype(float)  # per arm
        self.point_scales = [
            np.array([a.local_camera.cx / a.local_camera.fx, a.local_camera.cy / a.local_camera.fy])
            for a in self._arm_servos
        ]
        self.point_scale = self.point_scales[0]
        self.q_scale = state_scales(n, s.floating)
        high = np.full(observation_size(n) + 15 * (k - 1), OBS_CLIP, np.float32)
        low = -high
        high[14 : 15 * k : 15], low[14 : 15 * k : 15] = 1.0, 0.0  # each arm's detection flag
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._seed = int(sc.config.seed)
        self._sensed = None
        if render_mode == "foxglove":
            self._start_live(live)

    def _start_live(self, live) -> None:
        """The Foxglove server of ``render_mode="foxglove"`` on ``live`` (module docstring)."""
        from ..live import DEFAULT_PORT, LiveServer, parse_address

        host, port = parse_address(str(DEFAULT_PORT if live is None else live))
        self.live = LiveServer(host, port, name="tdacm env")

    def _quiet_log(self) -> None:
        """No logging in the env, and each arm's servo's ``perceive`` (the mode switch, the
        target filter's fusion) run once per period: the env observes the features it
        returns, then the servo's step reuses them."""
        from ..loop.logger import NullLog

        loop = self.loop
        loop.log = NullLog(loop.servo.desired_points)
        # a robot of several arms: one single-arm servo per arm (tdacm.loop.arms.ArmsServo)
        self._arm_servos = list(getattr(loop.servo, "arms", [loop.servo]))
        for servo in self._arm_servos:
            if not getattr(servo, "_compiled", False):  # the compiled servos perceive once
                servo.perceive = _perceive_once(type(servo).perceive.__get__(servo))

    @property
    def desired_points(self) -> np.ndarray:
        """The reference snapshot (normalized points in C_V)."""
        return self.loop.servo.desired_points

    @property
    def desired_depths(self) -> np.ndarray:
        return self.loop.servo.desired_depths

    # ------------------------------------------------------------------ helpers
    def _observe(self):
        """``(observation, seen, points, rmse, behind)`` at the loop's current state: the
        features of the servo's own first part (the detected points, or the robust servo's
        prediction from its target filter; servoing into contact, the touch law's pinned view
        in the tip camera once the probe has touched, as the vector env's:
        :meth:`~tdacm.loop.servo.VisualServo.period_view`)."""
        sensed = self._sensed = self.loop.sense()
        view, est = sensed.view, sensed.estimate
        loop = self.loop
        views = getattr(view, "arms", ()) or (view,)
        blocks, rmses, seen_all, behind_any, points0 = [], [], True, False, None
        # the squeeze's first part is the robot's (every arm's, then the squeeze's law), once
        robot_views = getattr(loop.servo, "period_views", None)
        outs = None
        if robot_views is not None:
            outs = robot_views(loop.plant.state.t, loop.dt, view, est, sensed.force)
        for k, (servo, v) in enumerate(zip(self._arm_servos, views, strict=True)):
            rmse = math.nan
            points = error = None
            behind = seen = False
            if outs is not None or getattr(servo, "_compiled", False):  # compiled, once
                if outs is not None:
                    out = take(outs, k)
                else:
                    out = servo.period_view(loop.plant.state.t, loop.dt, v, est, sensed.force)
                behind = bool(out.failure[0] == BEHIND)
                seen = bool(out.seen[0])
                if seen:
                    points, error, rmse = out.points, out.error, float(out.rmse[0])
            else:
                try:
                    parts = servo.perceive(loop.plant.state.t, loop.dt, v, est)
                except BehindVirtualCamera:
                    behind = True
                else:
                    _, _, seen, _, points, _, error, rmse, _ = parts
            seen = bool(seen) and not behind
            obs = observation(
                np.zeros((1, 6)) if error is None else np.asarray(error)[None],
                np.zeros((1, 4, 2)) if points is None else np.asarray(points)[None],
                [seen], est.q[None], est.qd[None], self.world.q_star, self.q_scale,
                self.point_scales[k],
            )[0]  # fmt: skip
            blocks.append(obs[:15])
            state = obs[15:]
            rmses.append(rmse)
            seen_all, behind_any = seen_all and seen, behind_any or behind
            points0 = points if k == 0 else points0
        rmse = max(rmses) if all(map(math.isfinite, rmses)) else math.nan
        obs = np.concatenate(blocks + [state])
        return obs, seen_all, points0, rmse, behind_any

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if seed is not None:  # a new model perturbation and sensor-noise stream
            self._reseed(int(self.np_random.integers(2**31)))
        loop, w = self.loop, self.world
        q = w.q0 + self.np_random.normal(0.0, self.init_noise, size=self.n)
        if loop.plant.system.floating:
            q[:2] = w.q0[:2]  # roll/pitch are not free: start level as the scenario
        loop.reset(q, w.qd0)
        self.steps = 0
        self.lost = 0
        self._reached = self._left = False
        self._wall0 = time.perf_counter()
        if self.live is not None:  # the static topics again: a reseed may move the target
            from ..live import RobotMessages

            self.live.attach(RobotMessages.of_world(self.assembly.world))
        obs, seen, _, rmse, _ = self._observe()
        return obs, {"rmse": rmse, "detected": seen, "loop_seed": self._seed}

    def _reseed(self, seed: int) -> None:
        from ..sim.assemble import build_loop, reseed

        if self.assembly.reseedable:
            self.assembly = reseed(self.assembly, seed)
        else:
            self.loop.close()
            self.assembly = build_loop(self.scenario, seed)
            self.loop = self.assembly.loop
            self._quiet_log()
        self._seed = seed

    def step(self, action):
        if self._sensed is None:
            raise gym.error.ResetNeeded("Cannot call env.step() before calling env.reset()")
        a = np.asarray(action, dtype=float)
        if a.shape != self.action_space.shape or not np.all(np.isfinite(a)):
            raise ValueError(
                f"action must be a finite array of shape {self.action_space.shape}, got {action!r}"
            )
        a = clip_action(a, self.action_space.low, self.action_space.high)
        state = self.loop.plant.state  # where the period starts (what a live client sees)
        if self.action_type == "twist":
            st = self.loop.act(self._sensed, twist=a * self.scale)
        else:
            st = self.loop.act(self._sensed, u=a * self._top)
        self.steps += 1
        q = self.loop.plant.state.q
        termination = st.termination if st.done else None
        if termination is None and (
            not np.all(np.isfinite(q))
            or (self.loop.plant.system.floating and np.max(np.abs(q[:2])) > MAX_TILT)
        ):
            termination = Termination.OUT_OF_ENVELOPE
        obs, seen, _, rmse, behind = self._observe()
        if behind and termination is None:
            termination = Termination.BEHIND_CAMERA
        self.lost = 0 if seen else self.lost + 1
        if termination is None and self.lost >= self.max_lost:
            termination = Termination.TARGET_LOST
        inside = seen and rmse <= self.success_rmse
        if self.hold:  # inside at the last step and not left since first inside
            self._left = self._left or (self._reached and not inside)
            self._reached = self._reached or inside
            inside = inside and not self._left and self.steps >= self.max_steps
        success = termination is None and inside
        if success:
            termination = Termination.SUCCESS
        reward = -rmse if seen else -self.lost_penalty
        if success:
            reward += self.success_bonus
        elif termination is not None:  # a failure: the steps left count as lost
            reward -= self.lost_penalty * (self.max_steps - self.steps)
        terminated = termination is not None
        reason = st.reason
        if reason is None and terminated:
            reason = {
                Termination.SUCCESS: f"rmse {rmse:.4g} <= {self.success_rmse}",
                Termination.TARGET_LOST: f"target not detected for {self.lost} steps",
                Termination.OUT_OF_ENVELOPE: f"roll/pitch beyond {MAX_TILT} rad or not finite",
                Termination.BEHIND_CAMERA: "a detected point maps behind the virtual camera",
            }.get(termination, str(termination))
        truncated = (not terminated) and self.steps >= self.max_steps
        if self.live is not None:
            ended = "ended early" if terminated and not success else "done"
            self._publish(state, st, ended if terminated or truncated else None, reason)
        info = {
            "rmse": rmse,
            "detected": seen,
            "success": bool(success),
            "termination": termination,
            "reason": reason,
        }
        return obs, float(reward), terminated, bool(truncated), info

    def _publish(self, state, st, ended: str | None, reason) -> None:
        """This step to the live server (``render_mode="foxglove"``), with the episode's
        progress (``ended``: how the episode ended, ``None`` while it runs)."""
        from ..live import row_of_step

        if self.live.publish(state.t, row_of_step(state, st), final=ended is not None) or ended:
            wall = time.perf_counter() - self._wall0
            self.live.progress(
                scenario=self.scenario.name,
                t=float(state.t),
                duration=self.max_steps * self.loop.dt,
                fraction=self.steps / self.max_steps,
                step=self.steps,
                wall_time=wall,
                speed=float(state.t) / wall if wall > 0 else 0.0,
                state=ended or "running",
                reason=reason if ended else None,
            )

    def render(self):
        """C_L's view at the current state, an RGB array ``(H, W, 3)`` (``render_mode =
        "rgb_array"``; the planar renderer, created on the first call); ``None`` for
        ``render_mode="foxglove"``, which publishes every step as it happens."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            from ..vision import PlanarRenderer

            self._renderer = PlanarRenderer(self.world.scene)
        sensors = self.loop.sensors
        q = self.loop.plant.state.q
        views = [  # each arm's C_L side by side, arm 0 on the left
            self._renderer.render(c.camera, c.pose(q))[:, :, :3]
            for c in getattr(sensors, "locals_", [sensors.local])
        ]
        return np.ascontiguousarray(np.concatenate(views, axis=1))

    def close(self):
        if self.live is not None:
            self.live.close()
            self.live = None
        if self.loop is not None:
            self.loop.close()

"""Gymnasium environment of the TD-ACM servoing task (registered as ``tdacm/TipServo-v0``).

The env drives the same :class:`tdacm.loop.ClosedLoop` as ``tdacm run`` and the campaigns, so
every scenario option applies: the robot, the sensor imperfections, the disturbances, the
command shaping, the estimator. Each step is one control period (paper: 20 ms): the action is
applied through the loop's blocks, the plant advances, and the new C_L view is observed.

Actions (``action_type``):

* ``"twist"`` (default): the virtual-camera twist ``[w; v]`` (angular first, in C_V, or in C_L
  for a fixed base), scaled by ``max_angular``/``max_linear`` from ``[-1, 1]^6``; it replaces
  the IBVS twist, then goes through the servo's mapping ``qdot_d = pinv(J_L^L) Ad v`` and its
  command shaping, and the scenario's low-level controller tracks the result.
* ``"actuators"``: raw inputs in ``[0, 1]`` scaled to ``[0, max_thrust]`` per motor and
  ``[0, max_tension]`` per tendon (fixed base: tensions only); no controller.

Observation (float32): the advanced-feature error ``p* - p*_d`` (6), the normalized image
points in C_V (8, zeros when not detected), a detection flag (1), then the state estimate
``q_hat``, ``qdot_hat`` (2 n; the true state when ``estimation.source = "true"``). Reward:
``-RMSE`` of the normalized points (``-lost_penalty`` when the target is not detected), plus
``success_bonus`` when the RMSE falls below ``success_rmse``, which ends the episode. The episode
also ends when the target stays lost for ``max_lost`` steps, when the loop terminates (plant
failure; the safety monitor too if ``safety=True``) or the state leaves a sane envelope; it is
truncated after ``max_steps``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class TipServoEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        scenario: str = "paper-in-fov",
        action_type: str = "twist",
        max_steps: int = 250,
        init_noise: float = 0.02,
        success_rmse: float = 0.01,
        success_bonus: float = 10.0,
        lost_penalty: float = 1.0,
        max_lost: int = 10,
        max_angular: float = 0.5,
        max_linear: float = 0.5,
        overrides: dict | None = None,
        safety: bool = False,
        render_mode: str | None = None,
    ):
        from ..sim.scenario import load_scenario

        if action_type not in ("twist", "actuators"):
            raise ValueError(f"action_type must be 'twist' or 'actuators', got {action_type!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps!r}")
        sc = load_scenario(scenario)
        if overrides:
            sc = sc.with_overrides(overrides, "env overrides")
        if not safety:
            sc = sc.with_overrides({"safety": {"enabled": False}}, "env")
        self.scenario = sc
        self.action_type = action_type
        self.max_steps = int(max_steps)
        self.init_noise = float(init_noise)
        self.success_rmse = float(success_rmse)
        self.success_bonus = float(success_bonus)
        self.lost_penalty = float(lost_penalty)
        self.max_lost = int(max_lost)
        self.scale = np.array([max_angular] * 3 + [max_linear] * 3)
        self.render_mode = render_mode
        self.loop = None
        self._build(int(sc["seed"]))
        s = self.loop.plant.system
        self.n = s.n
        if action_type == "twist":
            self.action_space = spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float32)
        else:
            self.action_space = spaces.Box(0.0, 1.0, shape=(s.n_u,), dtype=np.float32)
            self._top = np.r_[
                np.full(4, s.base.max_thrust) if s.floating else [],
                np.full(s.n_a, s.tendons.max_tension),
            ]
        # finite bounds (observations are clipped to them): feature errors, normalized points,
        # detection flag, q (angles, positions, strains), qdot
        high = np.concatenate(
            [np.full(6, 10.0), np.full(8, 5.0), [1.0], np.full(self.n, 100.0),
             np.full(self.n, 1000.0)]
        )  # fmt: skip
        low = -high
        low[14] = 0.0
        self.observation_space = spaces.Box(
            low.astype(np.float32), high.astype(np.float32), dtype=np.float32
        )

    def _build(self, seed: int) -> None:
        from ..sim.assemble import build_loop

        if self.loop is not None:
            self.loop.close()
        assembly = build_loop(self.scenario, seed, video=self.render_mode == "rgb_array")
        self.loop, self.world = assembly.loop, assembly.world
        self._seed = seed

    @property
    def desired_points(self) -> np.ndarray:
        """The reference snapshot (normalized points in C_V)."""
        return self.loop.servo.desired_points

    @property
    def desired_depths(self) -> np.ndarray:
        return self.loop.servo.desired_depths

    # ------------------------------------------------------------------ helpers
    def _observe(self):
        sensed = self.loop.sense()
        self._sensed = sensed
        view, est = sensed.view, sensed.estimate
        obs = np.zeros(self.observation_space.shape, dtype=np.float32)
        rmse = float("nan")
        if view.found:
            points, _, _, error, rmse = self.loop.servo.observe(view, est.q)
            obs[:6] = error
            obs[6:14] = np.asarray(points).ravel()
            obs[14] = 1.0
        obs[15 : 15 + self.n] = est.q
        obs[15 + self.n :] = est.qd
        np.clip(obs, self.observation_space.low, self.observation_space.high, out=obs)
        return obs, view, rmse

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if seed is not None:  # a new model perturbation and sensor-noise stream
            self._build(int(self.np_random.integers(2**31)))
        loop = self.loop
        w = self.world
        q = w.q0 + self.np_random.normal(0.0, self.init_noise, size=self.n)
        if loop.plant.system.floating:
            q[:2] = w.q0[:2]  # roll/pitch are not free: start level as the scenario
        loop.plant.reset(q, w.qd0)
        loop.reset()
        self.steps = 0
        self.lost = 0
        obs, view, rmse = self._observe()
        return obs, {"rmse": rmse, "detected": bool(view.found)}

    def step(self, action):
        a = np.asarray(action, dtype=float)
        if a.shape != self.action_space.shape or not np.all(np.isfinite(a)):
            raise ValueError(
                f"action must be a finite array of shape {self.action_space.shape}, got {action!r}"
            )
        a = np.clip(a, self.action_space.low, self.action_space.high)
        if self.action_type == "twist":
            st = self.loop.act(self._sensed, twist=a * self.scale)
        else:
            st = self.loop.act(self._sensed, u=a * self._top)
        self.steps += 1
        q = self.loop.plant.state.q
        diverged = bool(
            (st.done and st.reason is not None)
            or not np.all(np.isfinite(q))
            or (self.loop.plant.system.floating and np.max(np.abs(q[:2])) > 1.2)
        )
        obs, view, rmse = self._observe()
        self.lost = 0 if view.found else self.lost + 1
        success = bool(view.found and rmse <= self.success_rmse)
        reward = -rmse if view.found else -self.lost_penalty
        if success:
            reward += self.success_bonus
        terminated = success or diverged or self.lost >= self.max_lost
        truncated = (not terminated) and self.steps >= self.max_steps
        info = {
            "rmse": rmse,
            "detected": bool(view.found),
            "success": success,
            "diverged": diverged,
            "reason": st.reason,
            "termination": st.termination,
        }
        return obs, float(reward), bool(terminated), bool(truncated), info

    def render(self):
        if self.render_mode == "rgb_array":
            return self._sensed.readings.local.image
        return None

    def close(self):
        if self.loop is not None:
            self.loop.close()

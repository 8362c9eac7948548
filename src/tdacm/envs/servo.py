"""Gymnasium environment of the TD-ACM servoing task (registered as ``tdacm/TipServo-v0``).

Each step is one control period of a scenario (paper: 20 ms): the local camera C_L is rendered
and the target detected, then the action is applied, then the plant (true coupled model) is
integrated with RK4.

Actions (``action_type``):

* ``"twist"`` (default): the virtual-camera twist ``[w; v]`` (angular first, in C_V, or in C_L
  for a fixed base), scaled by ``max_angular``/``max_linear`` from ``[-1, 1]^6``.  It goes
  through the same chain as the paper's IBVS: ``qdot_d = pinv(J_L^L) Ad v`` over the commanded
  coordinates (no roll/pitch), integrated to ``q_d``, and the adaptive low-level controller
  (estimated model, thrust allocation, non-negative tensions) tracks it.
* ``"actuators"``: raw inputs in ``[0, 1]`` scaled to ``[0, max_thrust]`` per motor and
  ``[0, max_tension]`` per tendon (fixed base: tensions only); no controller.

Observation (float32): the advanced-feature error ``p* - p*_d`` (6), the normalized image
points (8, zeros when not detected), a detection flag (1), then proprioception ``q`` and
``qdot`` (2 n).  Reward: ``-RMSE`` of the normalized points (``-lost_penalty`` when the target
is not detected), plus ``success_bonus`` when the RMSE falls below ``success_rmse``, which ends
the episode.  The episode also ends when the target stays lost for ``max_lost`` steps or the
state leaves a sane envelope; it is truncated after ``max_steps``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..system.kernels import rk4_run


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
        render_mode: str | None = None,
    ):
        from ..sim.runner import Simulation, build
        from ..sim.scenario import load_scenario

        if action_type not in ("twist", "actuators"):
            raise ValueError(f"action_type must be 'twist' or 'actuators', got {action_type!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps!r}")
        self.scenario = load_scenario(scenario)
        self.setup = build(self.scenario, need_global=False)
        self._sim = Simulation(self.scenario)
        self.action_type = action_type
        self.max_steps = int(max_steps)
        self.init_noise = float(init_noise)
        self.success_rmse = float(success_rmse)
        self.success_bonus = float(success_bonus)
        self.lost_penalty = float(lost_penalty)
        self.max_lost = int(max_lost)
        self.scale = np.array([max_angular] * 3 + [max_linear] * 3)
        self.render_mode = render_mode
        s = self.setup.system
        self.n = s.n
        d = self.scenario.data
        self.dt, self.substeps = d["dt"], d["substeps"]
        self.desired_points, self.desired_depths = self._sim._desired_view(self.setup)
        if action_type == "twist":
            self.action_space = spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float32)
        else:
            self.action_space = spaces.Box(0.0, 1.0, shape=(s.n_u,), dtype=np.float32)
        # finite bounds (observations are clipped to them): feature errors, normalized points,
        # detection flag, q (angles, positions, strains), qdot
        high = np.concatenate(
            [
                np.full(6, 10.0),
                np.full(8, 5.0),
                [1.0],
                np.full(self.n, 100.0),
                np.full(self.n, 1000.0),
            ]
        )
        low = -high
        low[14] = 0.0
        self.observation_space = spaces.Box(
            low.astype(np.float32), high.astype(np.float32), dtype=np.float32
        )
        self._image = None

    # ------------------------------------------------------------------ helpers
    def _observe(self):
        from ..sim.runner import normalized_rmse
        from ..vision import virtual_camera_transform

        s, setup = self.setup.system, self.setup
        self._image = setup.render_local(self.q)
        gv = (
            virtual_camera_transform(s.base_pose(self.q), setup.local_pose(self.q))
            if s.floating
            else None
        )
        st = self.servo.step(self._image, gv)
        obs = np.zeros(self.observation_space.shape, dtype=np.float32)
        if st.found:
            obs[:6] = st.error
            obs[6:14] = np.asarray(st.points).ravel()
            obs[14] = 1.0
        obs[15 : 15 + self.n] = self.q
        obs[15 + self.n :] = self.qd
        rmse = normalized_rmse(st.points, self.desired_points) if st.found else float("nan")
        np.clip(obs, self.observation_space.low, self.observation_space.high, out=obs)
        return obs, st, rmse

    def reset(self, *, seed=None, options=None):
        from ..sim.runner import make_controller
        from ..vision import LOCAL_CAMERA, LocalCameraServo

        super().reset(seed=seed)
        d = self.scenario.data
        s, setup = self.setup.system, self.setup
        self.q = setup.q0 + self.np_random.normal(0.0, self.init_noise, size=self.n)
        if s.floating:
            self.q[:2] = setup.q0[:2]  # roll/pitch are not free: start level as the scenario
        self.qd = setup.qd0.copy()
        self.q_d = self.q.copy()
        if s.floating:
            self.q_d[:2] = 0.0
        self.ctl = make_controller(setup, int(self.np_random.integers(2**31)))
        ib = d["ibvs"]
        self.servo = LocalCameraServo(
            LOCAL_CAMERA,
            setup.target,
            self.desired_points,
            self.desired_depths,
            gain=ib["gain"],
            mode=ib["mode"],
        )
        self.steps = 0
        self.lost = 0
        obs, st, rmse = self._observe()
        return obs, {"rmse": rmse, "detected": bool(st.found)}

    def step(self, action):
        from ..vision import camera_joint_rates

        s, setup = self.setup.system, self.setup
        a = np.asarray(action, dtype=float)
        if a.shape != self.action_space.shape or not np.all(np.isfinite(a)):
            raise ValueError(
                f"action must be a finite array of shape {self.action_space.shape}, got {action!r}"
            )
        a = np.clip(a, self.action_space.low, self.action_space.high)
        if self.action_type == "twist":
            twist = a * self.scale
            rates = camera_joint_rates(
                s, self.q, twist, setup.tip_mount, jacobian_at="virtual" if s.floating else "actual"
            )
            qd_d = np.zeros(self.n)
            cmd = [i for i in range(self.n) if not (s.floating and i < 2)]
            qd_d[cmd] = rates[cmd]
            self.q_d = self.q_d + qd_d * self.dt
            u = self.ctl.step(self.q, self.qd, self.q_d, qd_d, np.zeros(self.n), self.dt).u
        else:
            top = np.r_[
                np.full(4, s.base.max_thrust) if s.floating else [],
                np.full(s.n_a, s.tendons.max_tension),
            ]
            u = a * top
        qs, qds, ok = rk4_run(
            self.q,
            self.qd,
            np.asarray(u, float),
            self.dt / self.substeps,
            self.substeps,
            self.substeps,
            s.model_arrays,
            s.loads.packed(),
        )
        self.steps += 1
        self.q, self.qd = qs[-1].copy(), qds[-1].copy()
        diverged = (
            (not ok)
            or not np.all(np.isfinite(self.q))
            or (s.floating and np.max(np.abs(self.q[:2])) > 1.2)
        )
        obs, st, rmse = self._observe()
        self.lost = 0 if st.found else self.lost + 1
        success = bool(st.found and rmse <= self.success_rmse)
        reward = -rmse if st.found else -self.lost_penalty
        if success:
            reward += self.success_bonus
        terminated = success or diverged or self.lost >= self.max_lost
        truncated = (not terminated) and self.steps >= self.max_steps
        info = {
            "rmse": rmse,
            "detected": bool(st.found),
            "success": success,
            "diverged": bool(diverged),
        }
        return obs, float(reward), bool(terminated), bool(truncated), info

    def render(self):
        if self.render_mode == "rgb_array":
            return self._image
        return None

    def close(self):
        self.setup.close()

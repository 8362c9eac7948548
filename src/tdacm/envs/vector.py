"""The servoing task as a Gymnasium vector env on the batched engine (``tdacm/TipServo-v0``).

``gym.make_vec("tdacm/TipServo-v0", num_envs=N, vectorization_mode="vector_entry_point")``
returns a :class:`TipServoVectorEnv`: N worlds of the scenario stepped in lockstep by the
compiled engine (:mod:`tdacm.batch`), with no Python per world per step. Each world is the
single env :class:`~tdacm.envs.servo.TipServoEnv` with the twist action: the same
observation (layout, scaling, float32, clipped), reward, success and failure endings and
``info`` keys (Gymnasium's vector form: one array per key and a ``_key`` mask of the worlds that
returned it, as :class:`gymnasium.vector.SyncVectorEnv` over single envs gives).

A step: the scaled twists replace the IBVS twists of the running worlds (a row of NaN keeps
the servo's own IBVS twist, a teacher for imitation; ``batch.data.twist`` holds the twist
each world applied)
(:func:`~tdacm.batch.engine.act`: the servo's mapping and shaping, the low-level
controller, the plant), then each world's tip camera delivers its next frame and the servo
perceives it (:func:`~tdacm.batch.engine.sense`: the view, the target filter, the mode
switch), in one compiled pass a world (:func:`~tdacm.batch.engine.act_sense`); the env reads
the servo's view (``batch.data.servo_out``). Endings: the engine's (:data:`ENGINE_ENDINGS`)
and the env's own, in the single env's order: out of envelope (roll/pitch beyond
:data:`~tdacm.envs.servo.MAX_TILT` or a non-finite state), behind camera, target lost for
``max_lost`` steps, success.

Autoreset: Gymnasium's default for vector envs, ``AutoresetMode.NEXT_STEP``: the step after a
world's episode ends resets that world (its action is ignored) and returns its first
observation with reward 0 and both flags false; the other worlds keep running.

Seeds: world ``i`` has its own generator, ``reset(seed=s)`` seeds it with ``s + i`` (a list
gives one seed per world), and a reset world draws from it, as the single env does after
``reset(seed=...)``, its loop seed (its model error, its sensor noise and disturbance streams)
then its initial offset (``init_noise``, roll and pitch kept). So world ``i`` starts as
``TipServoEnv.reset(seed=s + i)`` and its whole history depends on ``s + i`` only, not on the
number of worlds or the threads (tested). Unlike the single env, every reset (the autoreset
too) draws a new loop seed: each episode has another model error and noise.

Domain randomization (``randomize``, :class:`~tdacm.envs.options.Randomization`): a reset
world then draws its parameters from its generator, after its loop seed and initial offset
(:meth:`~tdacm.envs.options.Randomization.draw`), and runs with them as per-world
parameters of the engine (:class:`~tdacm.batch.params.WorldParams`): its rod's stiffness and
damping, the drone's and the rod's masses, the tendons' moment arms, C_L's pixel noise,
dropout and latency. Still a function of ``s + i`` only (tested).

What differs from the single env: the twist action only; the engine's scenario support
(the EKF's estimates, contact, servoing into contact with either force estimate, several
arms and the two-arm squeeze run). The state in the
observation is the controller's (the EKF's estimate on estimates). The observation holds the
features the servo works on, as the single env's: with the robust servo (the shipped
``ibvs.features = "predicted"``) the target filter's prediction after fusing the frame, else
the detected points; servoing into contact (``touch-target``), the touch law's view, pinned in
the tip camera C_L once the probe has touched (docs/contact.md). The recovery with the global camera runs batched as in the single env's loop (its
failure ends a world as ``recovery failed``). No ``render``.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .._compiling import compiling
from ..batch import engine as E
from ..loop.data import Termination
from ..loop.policy import OBS_CLIP, observation, observation_size, state_scales
from ..loop.servo import BEHIND as _BEHIND
from .options import EnvOptions, clip_action
from .servo import ENV_DEFAULTS, MAX_TILT, _merge

#: the view of a world's last frame in ``_status``: none, the servo's, a point behind C_V
NOT_SEEN, SEEN, BEHIND = 0, 1, 2


def _ending(name):
    """A :data:`~tdacm.batch.engine.TERMINATIONS` name as the single env's ``termination``
    (a :class:`~tdacm.loop.data.Termination`; the engine's own names stay strings)."""
    try:
        return Termination(name)
    except ValueError:
        return name


#: the engine's termination codes (:data:`~tdacm.batch.engine.TERMINATIONS`) as the env's
#: ``info["termination"]`` values
ENGINE_ENDINGS = tuple(None if n is None else _ending(n) for n in E.TERMINATIONS)

_REASONS = {
    Termination.TARGET_LOST: "target not detected for {lost} steps",
    Termination.OUT_OF_ENVELOPE: f"roll/pitch beyond {MAX_TILT} rad or not finite",
    Termination.BEHIND_CAMERA: "a detected point maps behind the virtual camera",
}


class TipServoVectorEnv(VectorEnv):
    """``num_envs`` worlds of the servoing task on the batched engine (module docstring).

    Options as :class:`~tdacm.envs.servo.TipServoEnv`: an
    :class:`~tdacm.envs.options.EnvOptions` ``options`` and/or its fields as keywords (the
    twist action only), plus ``threads``: threads
    stepping disjoint ranges of worlds (default: the machine's cores; the results do not
    depend on it). ``max_episode_steps`` (what ``make_vec`` passes from the registration)
    truncates as ``gym.make``'s time limit does the single env.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    @compiling("vector-env")
    def __init__(
        self,
        num_envs: int = 1,
        options: EnvOptions | None = None,
        render_mode: str | None = None,
        max_episode_steps: int | None = None,
        threads: int | None = None,
        **kwargs,
    ):
        from ..sim.assemble import build_loop
        from ..sim.batch import build_batch
        from ..sim.scenario import ScenarioError, load_scenario

        o = self.options = EnvOptions.of(options, kwargs)
        if o.action_type != "twist":
            raise ValueError(
                f"action_type: the vector env takes 'twist' only (the engine's act path), "
                f"got {o.action_type!r}; use gym.make for 'actuators'"
            )
        if render_mode is not None:
            raise ValueError(f"render_mode: the vector env does not render, got {render_mode!r}")
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs!r}")
        if max_episode_steps is not None and max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {max_episode_steps!r}")
        if threads is not None and int(threads) < 1:
            raise ValueError(f"threads must be >= 1, got {threads!r}")
        sc = load_scenario(o.scenario)
        ov = _merge(ENV_DEFAULTS, o.overrides or {})
        if not o.safety:
            ov = _merge(ov, {"safety": {"enabled": False}})
        sc = sc.with_overrides(ov, "env overrides")
        self.scenario = sc
        self.num_envs = N = int(num_envs)
        self.max_steps = int(o.max_steps)
        self.horizon = min(self.max_steps, int(max_episode_steps or self.max_steps))
        self.success_rmse = float(o.success_rmse)
        self.success_bonus = float(o.success_bonus)
        self.lost_penalty = float(o.lost_penalty)
        self.max_lost = int(o.max_lost)
        self.scale = None  # per arm, once the robot is known
        self.render_mode = None
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / sc.config.dt)))

        seed0 = int(sc.config.seed)
        self.assembly = a = build_loop(sc, seed0)
        loop = a.loop
        # the engine never ends a world by its duration: the env truncates
        duration = (self.horizon + 2) * loop.dt
        self.randomize = o.randomize
        params = None
        if o.randomize.latency:  # the latency buffers hold the largest draw
            from ..batch.params import WorldParams

            lat = max(int(o.randomize.latency), loop.sensors.local.model.latency_steps)
            params = WorldParams(latency=[lat] * N)
        try:
            self.batch = build_batch(
                sc, [seed0] * N, duration, threads=threads, assembly=a, params=params
            )
        except ScenarioError as exc:
            loop.close()
            raise ValueError(f"scenario: {exc}") from None
        self.threads = threads
        s = loop.plant.system
        self.n = n = s.n
        try:
            self.init_noise = o.initial_std(n)
        except ValueError:
            loop.close()
            raise
        self.floating = bool(s.floating)
        self.q0 = np.asarray(a.world.q0, float)
        self.qd0 = np.asarray(a.world.qd0, float)
        self.q_star = np.asarray(a.world.q_star, float)
        # a robot of k arms: 6 k actions, one 15-entry observation block per arm and the
        # state once, as the single env (tdacm.envs.servo)
        self.n_arms = k = int(self.batch.model.n_arms)
        self.scale = np.tile([o.max_angular] * 3 + [o.max_linear] * 3, k).astype(float)
        perceptions = list(getattr(loop.perception, "arms", None) or [loop.perception])
        self.point_scales = np.array([
            [p.local_camera.cx / p.local_camera.fx, p.local_camera.cy / p.local_camera.fy]
            for p in perceptions
        ])  # fmt: skip
        self.point_scale = self.point_scales[0]
        self.q_scale = state_scales(n, s.floating)

        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(6 * k,), dtype=np.float32)
        high = np.full(observation_size(n) + 15 * (k - 1), OBS_CLIP, np.float32)
        low = -high
        high[14 : 15 * k : 15], low[14 : 15 * k : 15] = 1.0, 0.0  # each arm's detection flag
        self.single_observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, N)
        self.observation_space = batch_space(self.single_observation_space, N)

        # per world: its generator, its episode's steps and lost count, the autoreset flag
        self._rngs = [None] * N
        self.steps = np.zeros(N, np.int64)
        self.lost = np.zeros(N, np.int64)
        self.hold = bool(o.hold_success)
        # per world: reached success_rmse in this episode; left it after reaching it
        self._reached = np.zeros(N, np.bool_)
        self._left = np.zeros(N, np.bool_)
        self._autoreset = np.zeros(N, np.bool_)
        self._obs = np.zeros((N, observation_size(n) + 15 * (k - 1)), np.float32)
        self._rmse = np.full(N, np.nan)
        self._status = np.zeros(N, np.int64)
        self._points = np.zeros((N, 4, 2))
        self._error = np.zeros((N, 6))
        self._all = np.ones(N, np.bool_)
        self._none = np.zeros(N, np.bool_)
        self._nan_twist = np.full((N, 6 * k), np.nan)
        self._started = False

    # ------------------------------------------------------------------ helpers
    @property
    def loop_seeds(self) -> np.ndarray:
        """Each world's loop seed (its model error and random streams), (N,)."""
        return self.batch.seeds.copy()

    def _parallel(self, kernel, args) -> None:
        E.parallel(kernel, args, self.num_envs, self.threads)

    def _start(self, which: np.ndarray) -> None:
        """Reset the worlds ``which``: a new loop seed then an initial offset, each drawn
        from the world's generator (module docstring)."""
        from ..batch.params import WorldParams
        from ..sim.batch import reseed_world

        idx = np.flatnonzero(which)
        q0 = np.empty((idx.size, self.n))
        for j, w in enumerate(idx):
            rng = self._rngs[w]
            seed = int(rng.integers(2**31))
            q = self.q0 + rng.normal(0.0, self.init_noise, size=self.n)
            if self.floating:
                q[:2] = self.q0[:2]  # roll/pitch are not free: start level as the scenario
            q0[j] = q
            params = WorldParams(**self.randomize.draw(rng)) if self.randomize.active else None
            reseed_world(self.batch, self.assembly, int(w), seed, params)
        self.batch.reset(which, q0, self.qd0)
        self.steps[which] = 0
        self.lost[which] = 0
        self._reached[which] = False
        self._left[which] = False
        self._autoreset[which] = False

    def _advance(self, acting: np.ndarray, twist: np.ndarray, which: np.ndarray) -> None:
        """The second half of the period of the running worlds of ``acting`` with the twists
        ``twist``, then the next frame of the worlds ``which`` (whether the engine still runs
        them or not) and their observation, RMSE and view status into the env's buffers: one
        compiled pass a world (:func:`~tdacm.batch.engine.act_sense`)."""
        d = self.batch.data
        self._parallel(E.act_sense, (self.batch.model, d, twist, acting, which))
        out = d.servo_out  # (N, arms, ...): each arm's view
        seen_arm = out.seen[:, :, 0] & (out.failure[:, :, 0] != _BEHIND)
        behind = (out.failure[:, :, 0] == _BEHIND).any(axis=1)
        seen = seen_arm.all(axis=1)
        self._status = np.where(behind, BEHIND, np.where(seen, SEEN, NOT_SEEN))
        self._points[:] = out.points[:, 0]
        self._error[:] = out.error[:, 0]
        # the state in the observation is the controller's: the EKF's estimate where the
        # scenario runs on estimates (as the single env's), else the true state
        on_estimates = self.batch.model.estimation.on
        q = d.estimation.q_hat if on_estimates else d.q
        qd = d.estimation.qd_hat if on_estimates else d.qd
        blocks = []
        for a in range(self.n_arms):
            obs_a = observation(
                out.error[:, a], out.points[:, a], seen_arm[:, a], q, qd, self.q_star,
                self.q_scale, self.point_scales[a],
            )  # fmt: skip
            blocks.append(obs_a[:, :15])
        obs = np.concatenate([*blocks, obs_a[:, 15:]], axis=1)
        with np.errstate(invalid="ignore"):  # the worst arm's, NaN if an arm sees nothing
            rmse = np.where(seen_arm, out.rmse[:, :, 0], np.nan).max(axis=1)
        self._obs[which] = obs[which]
        self._rmse[which] = rmse[which]

    # ------------------------------------------------------------------ the API
    @compiling("vector-env")
    def reset(self, *, seed=None, options=None):
        """Reset every world (or those of ``options["reset_mask"]``, a bool array (N,)).
        ``seed``: an int (world ``i`` gets ``seed + i``) or a list of N ints; ``None``
        keeps the worlds' generators (fresh ones on the first reset)."""
        N = self.num_envs
        which = np.ones(N, np.bool_)
        if options and "reset_mask" in options:
            which = np.asarray(options["reset_mask"])
            if which.shape != (N,) or which.dtype != np.bool_ or not which.any():
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({N},) with a True"
                )
        if seed is None:
            seeds = [None] * N
        elif isinstance(seed, int | np.integer):
            super().reset(seed=int(seed))
            seeds = [int(seed) + i for i in range(N)]
        else:
            seeds = list(seed)
            if len(seeds) != N:
                raise ValueError(f"seed: one per world ({N}), got {len(seeds)}")
        for w in np.flatnonzero(which):
            if seeds[w] is not None or self._rngs[w] is None:
                self._rngs[w], _ = seeding.np_random(seeds[w])
        if not self._started and not which.all():
            raise ValueError("options['reset_mask']: the first reset resets every world")
        self._started = True
        self._start(which)
        self._advance(self._none, self._nan_twist, which)
        status = self._status
        info = {
            "rmse": self._rmse.copy(),
            "_rmse": which.copy(),
            "detected": which & (status != NOT_SEEN),
            "_detected": which.copy(),
            "loop_seed": np.where(which, self.batch.seeds, 0).astype(np.int32),
            "_loop_seed": which.copy(),
        }
        return self._obs.copy(), info

    @compiling("vector-env")
    def step(self, actions):
        if not self._started:
            raise ResetNeeded("Cannot call step() before calling reset()")
        N = self.num_envs
        a = np.asarray(actions, dtype=float)
        width = 6 * self.n_arms
        finite = np.isfinite(a).all(axis=1) if a.shape == (N, width) else None
        if finite is None or not np.all(finite | np.isnan(a).all(axis=1)):
            raise ValueError(
                f"actions must be an array of shape ({N}, {width}), each row finite or all NaN "
                f"(the servo's own twist), got shape {a.shape}"
            )
        twist = clip_action(a, -1.0, 1.0) * self.scale
        d = self.batch.data
        resetting = self._autoreset.copy()
        stepping = ~resetting
        if resetting.any():  # the worlds are independent: these first, then one pass
            self._start(resetting)
        self._advance(stepping, twist, self._all)
        engine_end = stepping & ~d.active
        code = d.termination
        self.steps[stepping] += 1

        # the endings, in the single env's order (the first one names the ending)
        q = d.q
        out = ~np.isfinite(q).all(axis=1)
        if self.floating:
            with np.errstate(invalid="ignore"):
                out |= np.abs(q[:, :2]).max(axis=1) > MAX_TILT
        status, rmse = self._status, self._rmse
        seen = status == SEEN
        self.lost[stepping] = np.where(seen[stepping], 0, self.lost[stepping] + 1)
        envelope = stepping & ~engine_end & out
        free = stepping & ~engine_end & ~out
        behind = free & (status == BEHIND)
        free &= ~behind
        lost = free & (self.lost >= self.max_lost)
        free &= ~lost
        with np.errstate(invalid="ignore"):
            inside = seen & (rmse <= self.success_rmse)
        if self.hold:  # success: inside at the last step and not left since first inside
            self._left |= stepping & self._reached & ~inside
            self._reached |= stepping & inside
            success = free & inside & ~self._left & (self.steps >= self.horizon)
        else:
            success = free & inside
        terminated = engine_end | envelope | behind | lost | success
        failed = terminated & ~success

        reward = np.where(seen, -np.nan_to_num(rmse), -self.lost_penalty)
        reward += np.where(success, self.success_bonus, 0.0)
        reward -= np.where(failed, self.lost_penalty * (self.max_steps - self.steps), 0.0)
        truncated = stepping & ~terminated & (self.steps >= self.horizon)
        reward[resetting] = 0.0

        termination = np.full(N, None, object)
        reason = np.full(N, None, object)
        for w in np.flatnonzero(terminated):
            if engine_end[w]:
                termination[w] = ENGINE_ENDINGS[code[w]]
                reason[w] = f"the engine ended the world: {E.TERMINATIONS[code[w]]}"
            elif success[w]:
                termination[w] = Termination.SUCCESS
                reason[w] = f"rmse {rmse[w]:.4g} <= {self.success_rmse}"
            else:
                t = (
                    Termination.OUT_OF_ENVELOPE
                    if envelope[w]
                    else Termination.BEHIND_CAMERA
                    if behind[w]
                    else Termination.TARGET_LOST
                )
                termination[w] = t
                reason[w] = _REASONS[t].format(lost=self.lost[w])
        done = terminated | truncated
        d.active[done] = False  # the engine stops them; the next step resets them
        self._autoreset = done
        info = {
            "rmse": rmse.copy(),
            "_rmse": np.ones(N, np.bool_),
            "detected": np.where(resetting, status != NOT_SEEN, seen),
            "_detected": np.ones(N, np.bool_),
            "success": success,
            "_success": stepping.copy(),
            "termination": termination,
            "_termination": stepping.copy(),
            "reason": reason,
            "_reason": stepping.copy(),
        }
        if resetting.any():
            info["loop_seed"] = np.where(resetting, self.batch.seeds, 0).astype(np.int32)
            info["_loop_seed"] = resetting.copy()
        return self._obs.copy(), reward.astype(np.float64), terminated, truncated, info

    def close_extras(self, **kwargs):
        if self.assembly is not None:
            self.assembly.loop.close()
            self.assembly = None

"""Campaign runs on the batched engine (:mod:`tdacm.batch`): a chunk of K runs as one
:func:`~tdacm.sim.batch.build_batch` of K worlds on a Dask worker, each world's row the same
columns with the same meanings as the block loop's (:func:`tdacm.campaign.runner.execute_run`).

What a run samples must be what the engine can give each world:

* a distribution whose every draw is the same value (kind ``fixed``, a ``choice`` of one
  value) is applied to the chunk's shared scenario;
* ``initial.q`` and ``initial.qd`` vary per world (the batch's ``q0``, ``qd0`` rows);
* the keys of :data:`~tdacm.sim.batch.SCENARIO_KEYS` vary per world (the batch's
  :class:`~tdacm.batch.params.WorldParams`: C_L's pixel noise, dropout and latency, the
  target's tilt, yaw and position, the rod's Young's modulus, damping and density, the drone's
  mass, the tendons' radius), each world equal to the block loop of its run's scenario;
* the run's seed gives each world its controller's model error, its camera model with an
  intrinsics error and its random streams (:func:`~tdacm.sim.batch.build_batch`).

Anything else that varies between runs cannot be given per world: :func:`refusal` names it,
and the campaign runs on the block loop (``batched = "auto"``) or stops (``batched =
true``); a sampled parameter is never ignored. Without noise a batched row equals the block loop's to 1e-9; with noise the worlds
draw from the engine's own streams (docs/batch.md, "Determinism"), so rows differ run by run
and agree in distribution (``tests/campaign/test_batched.py``).
"""

from __future__ import annotations

import json
import time
import traceback

import numpy as np

from ..sim.batch import SCENARIO_KEYS
from .spec import CampaignSpec, sample_overrides

#: the sampled keys the engine varies per world (the batch's initial states and per-world
#: parameters)
PER_WORLD = ("initial.q", "initial.qd", *SCENARIO_KEYS)

#: worlds per chunk (one ``build_batch`` on a worker): large enough that the batch set-up
#: (one loop assembly, ~1 s) is small against the run, small enough to spread over workers
CHUNK = 50


def _constant(d: dict) -> bool:
    """Whether every draw of distribution ``d`` is the same value."""
    if d["kind"] == "fixed":
        return True
    if d["kind"] == "choice":
        vals = [json.dumps(v, sort_keys=True) for v in d["values"]]
        return len(set(vals)) == 1
    return False


def shared_overrides(spec: CampaignSpec, scenario_data: dict) -> dict:
    """The overrides every run of ``spec`` shares (its constant distributions), nested, as
    :func:`~tdacm.campaign.spec.sample_overrides` gives them to each run (an integer key
    rounded)."""
    drawn = sample_overrides(spec, scenario_data, 0)
    out: dict = {}
    for key in sorted(spec.distributions):
        if not _constant(spec.distributions[key]):
            continue
        parts = key.split(".")
        node, src = out, drawn
        for part in parts[:-1]:
            node, src = node.setdefault(part, {}), src[part]
        node[parts[-1]] = src[parts[-1]]
    return out


def varying_keys(spec: CampaignSpec) -> list[str]:
    """The keys whose draws differ between runs."""
    return [k for k in sorted(spec.distributions) if not _constant(spec.distributions[k])]


def refusal(spec: CampaignSpec) -> str | None:
    """Why ``spec`` cannot run on the batched engine, in one line naming the key (``None``:
    it can): a sampled key the engine does not vary per world, or a scenario it does not run
    (:func:`~tdacm.sim.batch.build_batch`'s refusal)."""
    from ..sim.batch import build_batch
    from ..sim.scenario import ScenarioError, load_scenario

    for key in varying_keys(spec):
        if key not in PER_WORLD:
            return (
                f"distributions.{key!r}: the batched engine cannot vary {key} per world "
                f"(it varies {', '.join(PER_WORLD)} and the seed's draws)"
            )
    if "robot.tendons.radius" in varying_keys(spec):
        if load_scenario(spec.scenario).config.robot.tendons.offsets is not None:
            return "distributions.'robot.tendons.radius': the tendons are given by offsets"
    try:
        base = load_scenario(spec.scenario)
        sc = base.with_overrides(shared_overrides(spec, base.data), spec.source)
        build_batch(sc, spec.run_seeds()[:1], duration=spec.duration, threads=1)
    except ScenarioError as exc:
        return str(exc)
    return None


def execute_chunk(spec_dict: dict, indices, seeds, threads: int = 1) -> list[dict]:
    """The rows of campaign runs ``indices`` (seeds ``seeds``) as one batch of worlds
    (executed on a worker); never raises: a run that cannot start or a chunk that fails
    becomes error rows."""
    spec = CampaignSpec(**spec_dict)
    t0 = time.perf_counter()
    rows, worlds, q0s, qd0s, cfgs = [], [], [], [], []
    try:
        from ..sim.scenario import load_scenario

        base = load_scenario(spec.scenario)
        shared = base.with_overrides(shared_overrides(spec, base.data), "campaign (batched)")
    except Exception as exc:  # noqa: BLE001 - the chunk's runs become error rows
        return [_error_row(i, s, exc) for i, s in zip(indices, seeds, strict=True)]
    for i, s in zip(indices, seeds, strict=True):
        row = {"run": int(i), "seed": int(s), "status": "ok", "error": "", "overrides": ""}
        try:
            ov = sample_overrides(spec, base.data, int(s))
            row["overrides"] = json.dumps(ov, sort_keys=True)
            cfg = base.with_overrides(ov, f"campaign run {i}").config  # the run's own checks
            q0s.append(np.asarray(cfg.initial.q, float))
            qd0s.append(None if cfg.initial.qd is None else np.asarray(cfg.initial.qd, float))
            cfgs.append(cfg)
            worlds.append(row)
        except Exception as exc:  # noqa: BLE001 - a failing run is data
            rows.append(_error_row(i, s, exc, row["overrides"]))
    if worlds:
        try:
            rows += _run_worlds(spec, shared, worlds, q0s, qd0s, threads, cfgs)
        except Exception as exc:  # noqa: BLE001 - the chunk's runs become error rows
            rows += [_error_row(r["run"], r["seed"], exc, r["overrides"]) for r in worlds]
    wall = (time.perf_counter() - t0) / max(1, len(rows))
    for r in rows:
        r["run_wall_s"] = wall
    return rows


def _error_row(i, s, exc, overrides: str = "") -> dict:
    return {
        "run": int(i),
        "seed": int(s),
        "status": "error",
        "success": False,
        "error": f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=8)}",
        "overrides": overrides,
    }


def _run_worlds(spec, scenario, rows, q0s, qd0s, threads, cfgs) -> list[dict]:
    """Run the worlds of ``rows`` (their seeds, initial states, scenario records ``cfgs``)
    and fill their rows."""
    from ..batch import engine as E
    from ..sim.assemble import build_loop
    from ..sim.batch import build_batch, world_params

    seeds = np.array([r["seed"] for r in rows], np.int64)
    a = build_loop(scenario, int(seeds[0]))
    t_build = time.perf_counter()
    params = world_params(scenario, cfgs, varying_keys(spec))
    batch = build_batch(
        scenario, seeds, spec.duration, np.array(q0s), threads, assembly=a, params=params
    )
    if any(qd is not None for qd in qd0s):
        zero = np.zeros(batch.q0.shape[1])
        batch.qd0 = np.array([zero if qd is None else qd for qd in qd0s])
    batch.reset()
    d, model = batch.data, batch.model
    periods = model.steps + 1
    nw, n = d.q.shape
    k = int(model.n_arms)
    rmse = np.full((periods, nw), np.nan)
    rmse_meas = np.full((periods, nw), np.nan)
    rmse_arms = np.full((periods, nw, k), np.nan)
    mode = np.full((periods, nw), -1, np.int64)
    found = np.zeros((periods, nw), np.bool_)
    recorded = np.zeros((periods, nw), np.bool_)
    q_log = np.zeros((periods, nw, n))
    # the EKF's estimate at each sample (the period's, as the block loop logs it)
    on_estimates = bool(model.estimation.on)
    q_hat_log = np.zeros((periods if on_estimates else 0, nw, n))
    u_log = np.zeros((periods, nw, d.u.shape[1]))
    sat = np.zeros((periods, nw, 2), np.bool_)
    # the block loop records no sample for a period that ends before the controller's output
    # is checked (ClosedLoop.act): the servo's behind-camera and recovery failures, a
    # non-finite command
    unrecorded = np.array([E.BEHIND_CAMERA, E.RECOVERY_FAILED, E.NON_FINITE])
    nan_twist = np.full((nw, 6 * k), np.nan)
    touch = None
    if model.touch.on:
        touch = _TouchLog(periods, d)
    elif model.touch.squeeze_on:
        touch = _SqueezeLog(periods, d)
    for p in range(periods):
        active = d.active.copy()
        if not active.any():
            break
        q_log[p] = d.q
        if touch is not None:
            touch.qd[p] = d.qd
        E.parallel(E.step_worlds, (model, d, nan_twist), nw, threads)
        if touch is not None:
            touch.record(p, d, model)
        rec = active & ~(~d.active & np.isin(d.termination, unrecorded))
        recorded[p] = rec
        rmse[p] = d.robot_out.rmse[:, 0]
        if on_estimates:
            q_hat_log[p] = d.estimation.q_hat
        rmse_meas[p] = d.robot_out.rmse_measured[:, 0]
        rmse_arms[p] = d.servo_out.rmse[:, :, 0]
        mode[p] = d.robot_out.mode[:, 0]
        found[p] = d.frame.detected[:, 0, 0]
        u_log[p] = d.u
        sat[p] = d.saturated
    wall = (time.perf_counter() - t_build) / nw
    t = np.arange(periods) * model.dt
    for w, row in enumerate(rows):
        sel = recorded[:, w]
        arrays = {
            "t": t[sel], "rmse": rmse[sel, w], "mode": mode[sel, w], "q": q_log[sel, w],
            "u": u_log[sel, w], "detected_local": found[sel, w],
            "thrust_saturated": sat[sel, w, 0], "tension_saturated": sat[sel, w, 1],
            "rmse_measured": rmse_meas[sel, w],
        }  # fmt: skip
        if on_estimates:
            arrays["q_hat"] = q_hat_log[sel, w]
        arrays["rmse_true"] = _true_rmse(a, params, w, model, arrays["q"])
        if k > 1:
            arrays["rmse_arms"] = rmse_arms[sel, w]
            arrays["rmse_true_arms"] = np.full((int(sel.sum()), k), np.nan)
        if touch is not None:
            arrays.update(touch.arrays(a, params, w, sel, arrays["q"], model))
        summary = _summary(a, arrays, d, w, wall, spec, row, params)
        _fill(spec, row, summary, arrays["t"], arrays["rmse"])
    return rows


class _TouchLog:
    """The touch servo's series of a batch's worlds, as the block loop's logger records them
    (:class:`~tdacm.loop.logger.RunLog`): per period the phase, the landings, the force
    estimate with its normal and the task's image error of the detected C_L points; per
    sample afterwards the contact forces and the true force along the normal, and the true
    C_L points' task error."""

    def __init__(self, periods: int, d):
        nw, n = d.q.shape
        self.qd = np.zeros((periods, nw, n))
        self.phase = np.full((periods, nw), -1, np.int64)
        self.landing = np.zeros((periods, nw), np.int64)
        self.force = np.full((periods, nw), np.nan)
        self.sigma = np.full((periods, nw), np.nan)
        self.normal = np.full((periods, nw, 3), np.nan)
        self.valid = np.zeros((periods, nw), np.bool_)
        self.local = np.full((periods, nw), np.nan)

    def record(self, p: int, d, model) -> None:
        td = d.touch
        self.phase[p] = td.state.phase[:, 0]
        self.landing[p] = td.state.landings[:, 0]
        ok = td.force_out.valid[:, 0]
        self.valid[p] = ok
        self.force[p] = np.where(ok, td.force_out.force[:, 0], np.nan)
        self.sigma[p] = np.where(ok, td.force_out.sigma[:, 0], np.nan)
        self.normal[p] = td.force_out.normals[:, 0]
        # the task's image error of every world's detected C_L points (normalized_rmse)
        diff = d.frame.xy[:, 0] - model.touch.refs.local_points
        err = np.sqrt(np.sum(diff * diff, axis=2).sum(axis=1) / 4.0)
        self.local[p] = np.where(d.frame.found[:, 0, 0], err, np.nan)

    def arrays(self, a, params, w, sel, q, model) -> dict:
        """World ``w``'s series at its recorded samples ``sel``, at the states ``q``."""
        from ..loop.touch import task_image_error

        contact = a.loop.log.contact
        qd = self.qd[sel, w]
        tip = np.zeros((q.shape[0], 3))
        rod = np.zeros((q.shape[0], 3))
        for i in range(q.shape[0]):
            tip[i], rod[i] = contact(q[i], qd[i])
        total = tip + rod
        valid = self.valid[sel, w]
        true = np.where(valid, np.einsum("ij,ij->i", total, self.normal[sel, w]),
                        np.linalg.norm(total, axis=1))  # fmt: skip
        truth = _truth(a, params, w, virtual=False)
        ref = model.touch.refs.local_points[w]
        local_true = np.full(q.shape[0], np.nan)
        if truth is not None:
            for i in range(q.shape[0]):
                local_true[i] = task_image_error(truth(q[i])[0], ref)
        return {
            "contact_tip": tip, "contact_rod": rod, "force_true": true,
            "force_hat": self.force[sel, w], "force_sigma": self.sigma[sel, w],
            "touch_phase": self.phase[sel, w], "touch_landing": self.landing[sel, w],
            "rmse_local": self.local[sel, w], "rmse_local_true": local_true,
        }  # fmt: skip


class _SqueezeLog(_TouchLog):
    """The squeeze's series of a batch's worlds, as the block loop's log of several arms
    records them (:class:`~tdacm.loop.touch_arms.ArmsTouchLog`): per period the run's and
    each arm's phase, the landings, each arm's force estimate with its normal and its task
    image error of the detected C_L points; per sample afterwards each arm's contact force
    and true force along its normal, and the true C_L points' task errors."""

    def __init__(self, periods: int, d):
        super().__init__(periods, d)
        nw, k = d.touch.squeeze_state.phase.shape
        self.phase_arms = np.full((periods, nw, k), -1, np.int64)
        self.force_arms = np.full((periods, nw, k), np.nan)
        self.normal_arms = np.full((periods, nw, k, 3), np.nan)
        self.local_arms = np.full((periods, nw, k), np.nan)

    def record(self, p: int, d, model) -> None:
        td = d.touch
        st = td.squeeze_state
        self.phase_arms[p] = st.phase
        self.phase[p] = st.phase.min(axis=1)  # the run's: the least advanced arm's
        self.landing[p] = st.landings[:, 0]
        ok = td.force_out.valid[:, 0]
        self.valid[p] = ok
        self.force_arms[p] = np.where(ok[:, None], td.force_out.force, np.nan)
        self.normal_arms[p] = td.force_out.normals
        diff = d.frame.xy - model.touch.arm_refs.local_points  # (worlds, arms, 4, 2)
        err = np.sqrt(np.sum(diff * diff, axis=3).sum(axis=2) / 4.0)
        self.local_arms[p] = np.where(d.frame.found[:, :, 0], err, np.nan)

    def arrays(self, a, params, w, sel, q, model) -> dict:
        """World ``w``'s series at its recorded samples ``sel``, at the states ``q``."""
        from ..loop.touch import task_image_error

        log = a.loop.log
        refs = model.touch.arm_refs.local_points[w]
        qd = self.qd[sel, w]
        m, k = q.shape[0], self.phase_arms.shape[2]
        per = np.zeros((m, k, 3))
        for i in range(m):
            per[i] = log.arm_forces(q[i], qd[i])
        valid = self.valid[sel, w]
        true = np.where(valid[:, None], np.einsum("ikj,ikj->ik", per, self.normal_arms[sel, w]),
                        np.linalg.norm(per, axis=2))  # fmt: skip
        hat = self.force_arms[sel, w]
        local_true = np.full((m, k), np.nan)
        for j in range(k):
            truth = _arm_truth(a, params, w, j, virtual=False)
            for i in range(m):
                local_true[i, j] = task_image_error(truth(q[i])[0], refs[j])
        local = self.local_arms[sel, w]
        return {
            "force_true_arms": true, "force_hat_arms": hat, "force_true": true.mean(axis=1),
            "force_hat": hat.mean(axis=1), "touch_phase": self.phase[sel, w],
            "touch_phase_arms": self.phase_arms[sel, w], "touch_landing": self.landing[sel, w],
            "contact_force_arms": np.linalg.norm(per, axis=2), "rmse_local_arms": local,
            "rmse_local_true_arms": local_true, "rmse_local": _worst_rows(local),
            "rmse_local_true": _worst_rows(local_true),
        }  # fmt: skip


def _worst_rows(x) -> np.ndarray:
    """Each row's largest finite value (NaN where a row has none)."""
    finite = np.isfinite(x)
    out = np.where(finite, x, -np.inf).max(axis=1)
    return np.where(finite.any(axis=1), out, np.nan)


def _fill(spec, row, summary, t, rmse) -> None:
    from .spec import succeeded
    from .store import ROW_FIELDS

    for k in ROW_FIELDS:
        row[k] = summary.get(k)
    row["success"] = succeeded(spec, {"t": t, "rmse": rmse}, summary)


def _reason(code: int, a, t, rmse, d, w) -> str | None:
    """The termination in words, as the block loop says it (the safety monitor's numbers,
    the drone's tilt, the servo's failure, the contact force)."""
    from ..batch import engine as E
    from ..loop.closed_loop import NON_FINITE_REASON, PLANT_FAILED_REASON, tumbled_reason
    from ..loop.plant import force_limit_reason
    from ..loop.safety import stop_reason
    from ..loop.servo import FAILURE_REASONS

    loop = a.loop
    t_end = d.k[w] * loop.dt
    if code == E.SAFETY:
        f = np.flatnonzero(np.isfinite(rmse))
        return stop_reason(loop.safety.params, rmse[f[-2]], rmse[f[-1]], t[f[-1]])
    if code == E.TUMBLED:
        return tumbled_reason(d.q[w], t_end)
    if code in (E.BEHIND_CAMERA, E.RECOVERY_FAILED):
        return FAILURE_REASONS.get(int(d.robot_out.failure[w, 0]))
    if code == E.FORCE_LIMIT:
        return force_limit_reason(float(d.force[w]), loop.plant.params.force_limit, t_end)
    return {E.PLANT_FAILED: PLANT_FAILED_REASON, E.NON_FINITE: NON_FINITE_REASON}.get(code)


def _true_rmse(a, params, w, model, q) -> np.ndarray:
    """World ``w``'s true image error at its last sample (NaN before: the summary reads the
    last finite one), from its own target and reference."""
    from ..loop.servo import normalized_rmse

    out = np.full(q.shape[0], np.nan)
    if not q.shape[0]:
        return out
    if model.n_arms > 1:  # the largest of the arms' (the block loop's ArmsLog)
        out[-1] = max(
            normalized_rmse(_arm_truth(a, params, w, k)(q[-1])[0], model.servo.desired_points[w, k])
            for k in range(model.n_arms)
        )
        return out
    truth = _truth(a, params, w)
    if truth is not None:
        pts, _ = truth(q[-1])
        out[-1] = normalized_rmse(pts, model.servo.desired_points[w, 0])
    return out


def _arm_truth(a, params, w, k, virtual: bool = True):
    """:func:`_truth` of arm ``k`` of a robot with several arms (its marker, with the world's
    board tilt)."""
    from dataclasses import replace

    from ..sim.batch import arm_scene
    from ..sim.blocks import truth_of

    world = replace(a.world, scene=arm_scene(a.world, params, w, k))
    return truth_of(world, a.loop.sensors.locals_[k], virtual=virtual)


def _truth(a, params, w, virtual: bool = True):
    """World ``w``'s true points (``q -> points``, :func:`~tdacm.sim.blocks.truth_of`) in the
    servo camera (``virtual``) or in C_L (the touch servo's task view): the loop's own unless
    the world has its own target pose."""
    from dataclasses import replace

    from ..batch.params import TARGET_FIELDS
    from ..sim.batch import world_scene
    from ..sim.blocks import truth_of

    loop = a.loop
    own = loop.log.truth if virtual else loop.log.truth_local
    if own is None or params is None or not params.given(TARGET_FIELDS):
        return own
    world = replace(a.world, scene=world_scene(a.world, params, w))
    return truth_of(world, loop.sensors.local, virtual=virtual)


def _summary(a, arrays, d, w, wall, spec, row, params) -> dict:
    """World ``w``'s summary: :func:`tdacm.sim.runner.run_summary`, the block loop's, from its
    logged ``arrays`` and how it ended, judged in its own scene (its target pose of
    ``params``: the target estimate's error)."""
    from dataclasses import replace

    from .._records import take
    from ..batch.engine import TERMINATIONS
    from ..loop.servo import filter_estimate
    from ..sim.batch import arm_scene, world_scene
    from ..sim.runner import RunOutcome, run_summary

    if d.servo_out.rmse.shape[1] > 1:  # several arms: arm 0's marker (the summary's)
        scene = arm_scene(a.world, params, w, 0)
    else:
        scene = world_scene(a.world, params, w)
    if scene is not a.world.scene:
        a = replace(a, world=replace(a.world, scene=scene))

    code = int(d.termination[w])
    t, mode = arrays["t"], arrays["mode"]
    switch = np.flatnonzero((mode[1:] == 0) & (mode[:-1] == 1))
    servo = take(take(d.servo, w), 0)
    outcome = RunOutcome(
        seed=int(row["seed"]),
        requested_duration=float(spec.duration if spec.duration is not None else t[-1]),
        wall_time_s=wall,
        terminated=code != 0,
        reason=_reason(code, a, t, arrays["rmse"], d, w) if code else None,
        termination=TERMINATIONS[code],
        switch_time=float(t[switch[0] + 1]) if switch.size else None,
        plan=None,
        target_estimate=filter_estimate(servo.filter),
    )
    return run_summary(a, arrays, outcome)

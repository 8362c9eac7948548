"""A scenario's batched engine: N worlds of its closed loop in lockstep
(:mod:`tdacm.batch`), assembled from the same blocks as the block loop.

:func:`build_batch` assembles the scenario's loop once (:func:`~tdacm.sim.assemble.build_loop`)
and packs its blocks; what depends on a world's seed is drawn per world as ``build_loop``
draws it for that seed: the controller's model error (``[model] perturbation``) and, with an
intrinsics error, the controller's camera model and the reference snapshot taken with it.
:func:`run_batch` runs the worlds to the end and returns their arrays.
"""

from __future__ import annotations

import numpy as np

from ..batch import Batch, BatchResult
from ..batch.control import controller_arrays
from ..batch.engine import BatchModel
from ..batch.pack import Unsupported, servo_model
from ..batch.plant import plant_arrays
from ..loop.sensors import perturbed_camera
from .assemble import build_loop, reference_snapshot
from .scenario import Scenario, ScenarioError, load_scenario


def build_batch(scenario, seeds, duration=None, q0=None, threads=None, assembly=None) -> Batch:
    """A :class:`~tdacm.batch.Batch` of ``scenario`` (a name, path or
    :class:`~tdacm.sim.scenario.Scenario`) with one world per seed of ``seeds``, for
    ``duration`` seconds (default the scenario's), from ``q0`` ((N, n) or (n,); default the
    scenario's initial state), stepped by ``threads`` threads (default: the machine's cores;
    the results do not depend on it). A scenario the engine does not run raises
    :class:`~tdacm.sim.scenario.ScenarioError` naming the key. ``assembly``: the scenario's
    loop already assembled (:func:`~tdacm.sim.assemble.build_loop`), reused instead of a new
    one (:func:`reseed_world` needs it)."""
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    seeds = np.asarray(seeds, np.int64).ravel()
    if sc.config.servo.policy is not None:
        raise ScenarioError(
            f"{sc.source}: the batched engine: servo.policy runs in the block loop "
            "(tdacm run, a campaign with batched = false or 'auto')"
        )
    if seeds.size == 0:
        raise ScenarioError("seeds: at least one world")
    a = build_loop(sc, int(seeds[0])) if assembly is None else assembly
    loop = a.loop
    try:
        base, cm = controller_arrays(loop.controller, loop.dt)
        pa, pm = plant_arrays(loop.plant)
        # the per-world rows: each seed's model error, drawn as build_loop draws it
        coords, dampings, params = [], [], []
        for s in seeds:
            a.model.reseed(int(s))
            ca, _ = controller_arrays(loop.controller, loop.dt)
            coords.append(ca.coord)
            dampings.append(ca.damping)
            params.append(ca.params)
        a.model.reseed(int(seeds[0]))
        ctl, refs = None, None
        err = loop.sensors.local.model.intrinsics_error
        if err > 0:  # each seed's camera model and the reference snapshot it takes
            robot, world = a.world.robot, a.world
            ctl, refs = [], []
            for s in seeds:
                cam = perturbed_camera(robot.local_camera, err, np.random.default_rng([int(s), 1]))
                ctl.append(cam)
                refs.append(
                    reference_snapshot(
                        loop.sensors.local, robot, world.target, world.scene, world.q_star, cam
                    )
                )
        sm = servo_model(loop, seeds.size, ctl, refs)
    except (Unsupported, ValueError) as exc:
        raise ScenarioError(f"{sc.source}: the batched engine: {exc}") from None
    dur = float(sc.data["duration"] if duration is None else duration)
    steps = int(round(dur / loop.dt))
    model = BatchModel(
        sm, base, cm, np.ascontiguousarray(coords), np.ascontiguousarray(dampings),
        np.ascontiguousarray(params), pa, pm,
        float(loop.dt), steps,
    )  # fmt: skip
    q0 = a.world.q0 if q0 is None else q0
    n_u = loop.plant.system.n_u
    return Batch(model, seeds, q0, a.world.qd0, n_u, threads)


def run_batch(scenario, seeds, duration=None, q0=None, log_states=False) -> BatchResult:
    """Run ``scenario``'s worlds of ``seeds`` (:func:`build_batch`) to the end."""
    return build_batch(scenario, seeds, duration, q0).run(log_states=log_states)


def reseed_world(batch: Batch, assembly, w: int, seed: int) -> None:
    """Give world ``w`` of ``batch`` (built by :func:`build_batch` with ``assembly``) the seed
    ``seed``: its rows in place, drawn as :func:`build_batch` draws them (the controller's model
    error; with an intrinsics error, the controller's camera model and the reference snapshot),
    and ``batch.seeds[w]``, from which :meth:`~tdacm.batch.Batch.reset` starts its random
    streams. Call ``batch.reset`` for the world afterwards."""
    seed = int(seed)
    if seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    loop, model = assembly.loop, batch.model
    assembly.model.reseed(seed)
    ca, _ = controller_arrays(loop.controller, loop.dt)
    model.coord[w] = ca.coord
    model.damping[w] = ca.damping
    model.control_params[w] = ca.params
    err = loop.sensors.local.model.intrinsics_error
    if err > 0:
        robot, world = assembly.world.robot, assembly.world
        cam = perturbed_camera(robot.local_camera, err, np.random.default_rng([seed, 1]))
        ref = reference_snapshot(
            loop.sensors.local, robot, world.target, world.scene, world.q_star, cam
        )
        one = servo_model(loop, 1, [cam], [ref])
        sm = model.servo
        sm.ctl_camera[w] = one.ctl_camera[0]
        sm.desired_points[w] = one.desired_points[0]
        sm.desired_depths[w] = one.desired_depths[0]
        sm.desired_features[w] = one.desired_features[0]
        sm.desired_interaction[w] = one.desired_interaction[0]
    batch.seeds[w] = seed

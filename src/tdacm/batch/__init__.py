"""The batched engine: N closed loops in lockstep, the blocks' compiled steps called for
every world.

:class:`Batch` holds a :class:`~tdacm.batch.engine.BatchModel` (the blocks' records stacked
over the worlds, from the blocks of an assembled :class:`~tdacm.loop.ClosedLoop`) and a
:class:`~tdacm.batch.engine.BatchData` (the state of every world) and steps them with
:func:`~tdacm.batch.engine.step_worlds` / :func:`~tdacm.batch.engine.run_worlds` (both
calls of the engine's one compiled entry, :func:`~tdacm.batch.engine.worlds`).
:func:`tdacm.sim.batch.build_batch` builds one from a scenario and seeds; the engine is tested
equal to the block loop (``tests/batch``). docs/batch.md: what runs batched, the speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._compiling import compiling
from .._records import replicate, take
from ..control.hierarchical import ControllerState, ControllerWork
from ..loop.arms import ArmsMemo
from ..loop.plant import PlantData
from ..loop.safety import SafetyState
from ..loop.sensors import CameraSensorState
from ..loop.servo import ServoOut, servo_state
from . import engine as E
from .engine import TERMINATIONS, BatchData, BatchModel, Frame
from .random import stream_state

__all__ = ["Batch", "BatchModel", "BatchData", "BatchResult", "TERMINATIONS"]

#: random streams of a world's seed: the cameras', the plant's, the estimation's (the
#: proprioceptive sensors and their start-up reading)
SENSOR_STREAM, PLANT_STREAM, ESTIMATION_STREAM = 1, 2, 3


@dataclass(frozen=True)
class BatchResult:
    """A batch run: per world (axis 1 of the series, axis 0 of the rest) the sample times
    ``t`` (samples,), the servo's normalized RMSE ``rmse`` and mode ``mode`` (0 IBVS,
    1 recovery, -1 after the world ended) per sample, the states ``q`` (samples, N, n) when
    logged, the final state ``q_final`` (N, n), the number of samples each world ran
    ``samples`` (N,) and why it ended (``termination``: a
    :class:`~tdacm.loop.data.Termination` value, or ``None`` when it ran to its end)."""

    t: np.ndarray
    rmse: np.ndarray
    mode: np.ndarray
    q: np.ndarray | None
    u: np.ndarray | None
    q_final: np.ndarray
    samples: np.ndarray
    termination: list

    @property
    def final_rmse(self) -> np.ndarray:
        """Each world's last finite RMSE (NaN if none)."""
        out = np.full(self.rmse.shape[1], np.nan)
        for w in range(self.rmse.shape[1]):
            f = np.flatnonzero(np.isfinite(self.rmse[:, w]))
            if f.size:
                out[w] = self.rmse[f[-1], w]
        return out

    def late_rmse(self, seconds: float = 1.0) -> np.ndarray:
        """Each world's RMS of the finite RMSE samples of its last ``seconds`` (the campaigns'
        windowed success criterion, :func:`tdacm.sim.runner.late_rmse`)."""
        out = np.full(self.rmse.shape[1], np.nan)
        for w in range(self.rmse.shape[1]):
            t_end = self.t[self.samples[w] - 1] if self.samples[w] else 0.0
            sel = (self.t >= t_end - seconds - 1e-9) & np.isfinite(self.rmse[:, w])
            if sel.any():
                out[w] = float(np.sqrt(np.mean(self.rmse[sel, w] ** 2)))
        return out


def empty_data(model: BatchModel, n_worlds: int, n: int, n_u: int, estimation,
               touch) -> BatchData:  # fmt: skip
    """The state of ``n_worlds`` worlds of ``n`` coordinates and ``n_u`` inputs, each block's
    state as its block makes it (the arms' with an arm axis; ``estimation`` and ``touch`` one
    world's :class:`~tdacm.estimation.block.EstimationData` and
    :class:`~tdacm.loop.touch.TouchData`; then :func:`~tdacm.batch.engine.reset_worlds`)."""
    k = int(model.n_arms)
    sensors = take(model.sensor, 0)
    latency = int(np.max(model.sensor.latency))
    servo = take(take(model.servo, 0), 0)
    ns = int(servo.strains[1] - servo.strains[0])
    window = _window(model)
    per_arm = lambda record: replicate(replicate(record, k), n_worlds)  # noqa: E731
    frame = Frame(np.zeros(1, np.bool_), np.zeros(1, np.bool_), np.zeros((4, 2)),
                  np.zeros((4, 2)), np.ones(4), np.zeros(1, np.int64))  # fmt: skip
    return BatchData(
        q=np.zeros((n_worlds, n)),
        qd=np.zeros((n_worlds, n)),
        k=np.zeros(n_worlds, np.int64),
        active=np.zeros(n_worlds, np.bool_),
        termination=np.zeros(n_worlds, np.int64),
        request=np.zeros(n_worlds, np.bool_),
        rng_sensors=np.zeros((n_worlds, 2), np.uint64),
        rng_plant=np.zeros((n_worlds, 2), np.uint64),
        rng_estimation=np.zeros((n_worlds, 2), np.uint64),
        sensor=per_arm(CameraSensorState.empty(take(sensors, 0), latency)),
        frame=per_arm(frame),
        servo=per_arm(servo_state(servo, n, ns, window)),
        servo_out=per_arm(ServoOut.empty(n, ns)),
        robot_out=replicate(ServoOut.empty(n, ns), n_worlds),
        memo=replicate(ArmsMemo.initial(), n_worlds),
        estimation=replicate(estimation, n_worlds),
        touch=replicate(touch, n_worlds),
        controller=replicate(ControllerState.initial(n), n_worlds),
        work=replicate(ControllerWork.empty(n), n_worlds),
        safety=replicate(SafetyState.initial(), n_worlds),
        plant=replicate(PlantData.initial(take(model.plant, 0)), n_worlds),
        u=np.zeros((n_worlds, n_u)),
        tau=np.zeros((n_worlds, n)),
        q_ref=np.zeros((n_worlds, n)),
        saturated=np.zeros((n_worlds, 2), np.bool_),
        force=np.zeros(n_worlds),
        q_next=np.zeros((n_worlds, n)),
        qd_next=np.zeros((n_worlds, n)),
        qdd_next=np.zeros((n_worlds, n)),
    )


def _window(model: BatchModel) -> int:
    """The robust servo's target-filter window (0 for the measured servo)."""
    servo = take(take(model.servo, 0), 0)
    return int(servo.filter.record.window) if servo.robust else 0


class Batch:
    """N worlds of one scenario in lockstep (module docstring).

    Parameters
    ----------
    model:
        The constants (:func:`tdacm.sim.batch.build_batch` packs them).
    seeds:
        One seed per world: its random streams (sensor noise and dropouts, downwash noise,
        turbulence); its model error and camera model are in ``model`` already.
    q0, qd0:
        Initial states (N, n) (``qd0`` default zero).
    n_u:
        Number of inputs (thrusts and tensions).
    threads:
        Threads stepping disjoint ranges of worlds (default: the machine's cores); the
        results do not depend on it.
    estimation:
        One world's :class:`~tdacm.estimation.block.EstimationData` (the filter's and the
        sensors' state records, replicated over the worlds).
    touch:
        One world's :class:`~tdacm.loop.touch.TouchData` (the touch law's and the force
        estimate's state records).
    """

    def __init__(
        self, model: BatchModel, seeds, q0, qd0=None, n_u: int = 0, threads=None,
        estimation=None, touch=None,
    ):  # fmt: skip
        self.model = model
        self.threads = threads
        self.seeds = np.asarray(seeds, np.int64).ravel()
        q0 = np.atleast_2d(np.asarray(q0, float))
        n_worlds = self.seeds.shape[0]
        if q0.shape[0] == 1 and n_worlds > 1:
            q0 = np.repeat(q0, n_worlds, axis=0)
        if q0.shape[0] != n_worlds:
            raise ValueError(f"q0 needs one row per world ({n_worlds}), got {q0.shape[0]}")
        self.q0 = np.ascontiguousarray(q0)
        self.qd0 = np.zeros_like(self.q0) if qd0 is None else np.broadcast_to(qd0, q0.shape).copy()
        self.n_worlds = n_worlds
        #: the per-world parameters the batch was built with (``None``: the scenario's)
        self.params = None
        self.data = empty_data(model, n_worlds, q0.shape[1], n_u, estimation, touch)
        self.reset()

    @property
    def dt(self) -> float:
        return self.model.dt

    @compiling("engine")
    def reset(self, which=None, q0=None, qd0=None) -> None:
        """Restart the worlds ``which`` (bool mask, default all) from ``q0``/``qd0`` (rows
        for those worlds; default the batch's initial states), their random streams rewound
        to their seeds' starts."""
        which = np.ones(self.n_worlds, np.bool_) if which is None else np.asarray(which, bool)
        q0s, qd0s = self.q0.copy(), self.qd0.copy()
        if q0 is not None:
            q0s[which] = q0
        if qd0 is not None:
            qd0s[which] = qd0
        d = self.data
        d.rng_sensors[which] = stream_state(self.seeds[which], SENSOR_STREAM)
        d.rng_plant[which] = stream_state(self.seeds[which], PLANT_STREAM)
        d.rng_estimation[which] = stream_state(self.seeds[which], ESTIMATION_STREAM)
        E.reset_worlds(self.model, d, which, q0s, qd0s)

    @compiling("engine")
    def step(self, twist=None) -> None:
        """One control period of every running world; ``twist`` (N, 6) replaces the IBVS
        twist (NaN rows: the IBVS twist)."""
        if twist is None:
            twist = np.full((self.n_worlds, 6), np.nan)
        args = (self.model, self.data, np.ascontiguousarray(twist, float))
        E.parallel(E.step_worlds, args, self.n_worlds, self.threads)

    @compiling("engine")
    def run(self, log_states: bool = False, log_inputs: bool = False) -> BatchResult:
        """Reset, then run every world to its end (``model.steps + 1`` samples or a
        termination)."""
        self.reset()
        d = self.data
        periods = self.model.steps + 1
        nw, n = d.q.shape
        log_q = np.zeros((periods if log_states else 0, nw, n))
        log_u = np.zeros((periods if log_inputs else 0, nw, d.u.shape[1]))
        log_rmse = np.full((periods, nw), np.nan)
        log_mode = np.full((periods, nw), -1, np.int64)
        args = (self.model, d, periods, log_q, log_rmse, log_mode, log_u)
        E.parallel(E.run_worlds, args, self.n_worlds, self.threads)
        samples = np.minimum(d.k + 1, periods)
        return BatchResult(
            t=np.arange(periods) * self.model.dt,
            rmse=log_rmse,
            mode=log_mode,
            q=log_q if log_states else None,
            u=log_u if log_inputs else None,
            q_final=d.q.copy(),
            samples=samples,
            termination=[TERMINATIONS[c] for c in d.termination],
        )

"""The second compiling process of a first ``tdacm run`` on a cold numba cache, when the run's
scenario is known (:func:`tdacm.loop.precompile.start` with the scenario).

numba compiles one kernel at a time and holds the GIL meanwhile; a second *process* compiles
in parallel and shares the result through numba's on-disk cache. The main process builds the
loop, then runs its first period in order: the sensors, perception, the servo (its steps are
the largest share of the run's compile: docs/benchmarks.md, "What compiles"), the low-level
controller, the plant. This process takes what the main process reaches last:

1. the plant's integrator (:func:`tdacm.loop.precompile.compile_second_half`), which the
   main process's warm-up waits for;
2. the same loop, built from the scenario (the model's kernels the main process compiled
   meanwhile load from the cache);
3. the servo's command step (``servo_command``, the second half of the servo's period), the
   plant's step (``plant_step``) and the controller's (``controller_step``), called once
   with the argument types of the run's own calls, so that the main process loads them when
   its first period reaches them.

Anything that fails here (a scenario whose blocks take other inputs, a kill at the end of the
run) costs nothing but this process's time: the main process compiles what is missing
itself. ``tests/loop/test_precompile.py`` checks that this process compiles no signature the
loop does not use.
"""

from __future__ import annotations

import os
import pickle
import sys

import numpy as np

from ..loop.data import ServoCommand
from ..loop.precompile import compile_second_half
from ..loop.servo import RobustServo, ServoOut, VisualServo, servo_command
from .assemble import build_loop


def compile_ahead(scenario) -> None:
    """Compile (or load) the plant's integrator, then the servo's command step and the plant's
    and the controller's steps of ``scenario``'s loop (module docstring)."""
    compile_second_half()
    loop = build_loop(scenario).loop
    try:
        plant = loop.plant
        plant.reset()
        est = loop.estimator.reset(plant.state.t)
        q = np.ascontiguousarray(est.q, dtype=float)
        _servo_command(loop.servo, q, loop.dt)
        loop.controller.reset(est)
        plant.advance(np.zeros(plant.system.n_u), loop.dt)
        zeros = np.zeros(len(q))
        cmd = ServoCommand(loop.servo.mode, q.copy(), zeros, zeros.copy(), np.zeros(6))
        loop.controller.step(est, cmd, loop.dt)
    finally:
        loop.close()


def _servo_command(servo, q, dt: float) -> None:
    """:func:`~tdacm.loop.servo.servo_command` once with the argument types of the servo's
    period (:meth:`~tdacm.loop.servo.VisualServo.compiled_step`: no C_G frame offered, no
    external twist), on the servo's state as built: numba compiles and caches before it runs,
    so what this call computes does not matter (the servos built on other parts, touch and
    several arms, have no such step)."""
    if type(servo) not in (VisualServo, RobustServo):
        return
    p = servo.params
    out = ServoOut.empty(len(q), int(p.strains[1] - p.strains[0]))
    m_count = p.marker_centres.shape[0]
    corners, seen = np.zeros((m_count, 4, 2)), np.zeros(m_count, np.bool_)
    no_twist = np.full(6, np.nan)
    try:
        servo_command(p, servo.state, servo.system.model_arrays, 0.0, float(dt), q, False,
                      no_twist, False, corners, seen, out)  # fmt: skip
    except Exception:  # noqa: S110 - compiled and cached already; its arithmetic is not used
        pass


def _main(path: str) -> int:
    with open(path, "rb") as f:
        scenario = pickle.load(f)
    os.unlink(path)
    compile_ahead(scenario)
    return 0


if __name__ == "__main__":  # pragma: no cover - run as a subprocess by precompile.start()
    sys.exit(_main(sys.argv[1]))

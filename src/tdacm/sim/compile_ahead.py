"""The second compiling process of a first ``tdacm run`` on a cold numba cache, when the run's
scenario is known (:func:`tdacm.loop.precompile.start` with the scenario).

numba compiles one kernel at a time and holds the GIL meanwhile; a second *process* compiles
in parallel and shares the result through numba's on-disk cache. The main process builds the
loop, then runs its first period in order: the sensors, perception, the servo (its steps are
the largest share of the run's compile: docs/benchmarks.md, "What compiles"), the low-level
controller, the plant. This process takes the ends the main process reaches last:

1. the plant's integrator (:func:`tdacm.loop.precompile.compile_second_half`), which the
   main process's warm-up waits for;
2. the same loop, built from the scenario (the model's kernels the main process compiled
   meanwhile load from the cache);
3. the plant's step (``plant_step``) and the controller's (``controller_step``), called
   once through the blocks with the argument types of the run's own calls, so that the main
   process loads them when its first period reaches them.

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
from .assemble import build_loop


def compile_ahead(scenario) -> None:
    """Compile (or load) the plant's integrator, then the plant's and the controller's steps
    of ``scenario``'s loop (module docstring)."""
    compile_second_half()
    loop = build_loop(scenario).loop
    try:
        plant = loop.plant
        plant.reset()
        est = loop.estimator.reset(plant.state.t)
        loop.controller.reset(est)
        plant.advance(np.zeros(plant.system.n_u), loop.dt)
        zeros = np.zeros(len(est.q))
        cmd = ServoCommand(loop.servo.mode, est.q.copy(), zeros, zeros.copy(), np.zeros(6))
        loop.controller.step(est, cmd, loop.dt)
    finally:
        loop.close()


def _main(path: str) -> int:
    with open(path, "rb") as f:
        scenario = pickle.load(f)
    os.unlink(path)
    compile_ahead(scenario)
    return 0


if __name__ == "__main__":  # pragma: no cover - run as a subprocess by precompile.start()
    sys.exit(_main(sys.argv[1]))

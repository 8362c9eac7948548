"""Cost of the flight aerodynamics in the plant step.  Run:
``python benchmarks/bench_aero.py`` (``--json`` for a machine-readable line).

Times one control period of the plant's integration (``substeps`` RK4 steps inside numba, as
:class:`tdacm.loop.plant.Plant` runs it) of the paper's floating TD-ACM in a bent, moving
state, without aerodynamics (``rk4_run``) and with all of them (rotor wake, rod and tip drag,
drone drag, wind: ``rk4_run_aero``); medians of interleaved repeats, and their ratio (target:
at most 1.2).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

import tdacm
from tdacm.bench import batch_times
from tdacm.system import kernels as K
from tdacm.system.aero import aero_array


def _median(fn, number, repeats):
    return float(np.median(batch_times(fn, number, repeats)))


def run(repeats: int = 15, number: int = 2000, substeps: int = 4) -> dict:
    s = tdacm.paper_system()
    m, loads = s.model_arrays, s.loads.packed()
    q = np.zeros(s.n)
    q[3:6] = [0.1, -0.2, 3.0]
    q[6:] = [0.3, -0.2]
    qd = np.r_[0.05, -0.03, 0.01, 0.4, -0.2, 0.1, 0.5, 0.3]
    u = np.r_[np.full(4, 9.81 * s.total_mass / 4), 1.0, 0.5, 0.0, 0.2]
    aero = aero_array(s, wind=[2.0, 1.0, 0.0])
    h = 0.02 / substeps

    def plain():
        K.rk4_run(q, qd, u, h, substeps, substeps, m, loads)

    def air():
        K.rk4_run_aero(q, qd, u, h, substeps, substeps, m, loads, aero)

    plain()
    air()
    t_plain, t_air = [], []
    for _ in range(repeats):  # interleaved, so that load changes hit both alike
        t_plain.append(_median(plain, number, 1))
        t_air.append(_median(air, number, 1))
    a, b = float(np.median(t_plain)), float(np.median(t_air))
    return {"plant_step_us": a * 1e6, "plant_step_aero_us": b * 1e6, "ratio": b / a}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args()
    r = run(args.repeats)
    if args.json:
        print(json.dumps(r))
    else:
        print(
            f"plant step (4 RK4 substeps): {r['plant_step_us']:.1f} us without aerodynamics, "
            f"{r['plant_step_aero_us']:.1f} us with them: ratio {r['ratio']:.3f}"
        )

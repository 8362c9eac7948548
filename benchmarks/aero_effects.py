"""Size of the aerodynamic effects on the paper's TD-ACM (docs/aerodynamics.md, "Size of the
effects").  Run: ``python benchmarks/aero_effects.py`` (``--json`` for one machine-readable line).

* the air's force on the rod and on the tip camera of the hovering drone, rod hanging and bent
  (:func:`tdacm.system.aero.section_air_loads`);
* the static tip position of the arm under a drone held at 3 m with its motors at hover thrust
  (``fixed_thrusts``) and constant tendon tensions, without and with the aerodynamics (the wake;
  the wake and a 3 m/s wind): the equilibrium ``qdd(q_s) = 0`` of the coupled model with the
  aerodynamic loads of eq. (16), solved by Newton's method (:func:`scipy.optimize.fsolve`).
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from scipy.optimize import fsolve

import tdacm
from tdacm.aero import Aerodynamics
from tdacm.base import FixedBase
from tdacm.system import kernels as K
from tdacm.system.aero import aero_array, section_air_loads
from tdacm.system.tdacm import TDACM


def forces_in_hover() -> dict:
    """Force (N) of the air on the rod and on the camera, drone hovering in still air."""
    s = tdacm.paper_system()
    out = {}
    for name, q_s in (("hanging", (0.0, 0.0)), ("bent_0.5", (-0.5, 0.0)), ("bent_1", (-1.0, 0.0))):
        q = np.zeros(s.n)
        q[5] = 3.0
        q[6:] = q_s
        u = np.zeros(s.n_u)
        u[:4] = 9.81 * s.total_mass / 4
        a = aero_array(s, Aerodynamics())
        p, f, tip = section_air_loads(s, q, np.zeros(s.n), u, a)
        m = s.model_arrays
        sl = slice(s._rod_steps[0], s._rod_steps[1])
        w = m.step_w[sl][m.step_load[sl] == K.LOAD_DISTRIBUTED]  # the Gauss weights (m)
        rod = w @ f
        out[name] = {
            "rod_N": float(np.linalg.norm(rod)),
            "rod_max_N_per_m": float(np.linalg.norm(f, axis=1).max()),
            "camera_N": float(np.linalg.norm(tip)),
        }
    return out


def _held_system():
    p = tdacm.paper_system()
    q = np.zeros(p.n)
    q[5] = 3.0
    return p, TDACM(p.arms[0].rod, p.arms[0].tendons, FixedBase(pose=p.base_pose(q)),
                    p.arms[0].attachment)  # fmt: skip


def static_tips(tensions=(3.0, 0.5, 0.5, 0.5), wind: float = 3.0) -> dict:
    """Static tip position (m) of the held arm without air, in the wake, in wake and wind."""
    floating, s = _held_system()
    hover = 9.81 * floating.total_mass / 4
    u = np.asarray(tensions, float)
    m, loads = s.model_arrays, s.loads.packed()
    cases = {
        "no_air": None,
        "wake": aero_array(s, Aerodynamics(fixed_thrusts=(hover,) * 4)),
        f"wake_wind_{wind:g}": aero_array(
            s, Aerodynamics(fixed_thrusts=(hover,) * 4), wind=(wind, 0.0, 0.0)
        ),
    }
    out = {}
    zero = np.zeros(s.n)
    for name, a in cases.items():

        def qdd(q, a=a):
            if a is None:
                return K.forward_dynamics(q, zero, u, m, loads)[0]
            return K.forward_dynamics_aero(q, zero, u, m, loads, a)[0]

        q = fsolve(qdd, np.zeros(s.n), xtol=1e-12)
        assert np.max(np.abs(qdd(q))) < 1e-8
        out[name] = {"q_s": q.tolist(), "tip": s.tip_pose(q)[:3, 3].tolist()}
    ref = np.array(out["no_air"]["tip"])
    for name in cases:
        out[name]["tip_shift_mm"] = float(1e3 * np.linalg.norm(np.array(out[name]["tip"]) - ref))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    res = {"forces_in_hover": forces_in_hover(), "static_tip": static_tips()}
    if args.json:
        print(json.dumps(res))
        return 0
    for name, f in res["forces_in_hover"].items():
        rod, peak, cam = (1e3 * f[k] for k in ("rod_N", "rod_max_N_per_m", "camera_N"))
        print(f"hover, rod {name}: rod {rod:.3g} mN (max {peak:.3g} mN/m), camera {cam:.3g} mN")
    for name, t in res["static_tip"].items():
        q_s = np.round(t["q_s"], 5).tolist()
        print(f"held arm, tensions (3, 0.5, 0.5, 0.5) N, {name}: q_s = {q_s}, "
              f"tip shift {t['tip_shift_mm']:.3g} mm")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

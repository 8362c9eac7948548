"""Two of the paper's TD-CRs under one quadrotor (several rods on one base).

The drone hovers under a simple attitude/altitude stabilizer while the two rods bend in
opposite directions (rod 0 pulls its +y tendon, rod 1 its -y tendon after 0.5 s).  Prints the
layout of ``q`` and ``u`` and the two tips; writes ``out/dual_tdcr/dual.npz``.

Run: ``python examples/dual_tdcr.py``
"""

from pathlib import Path

import numpy as np

import tdacm
from tdacm.demo import hover_stabilizer


def main(out="out/dual_tdcr", duration=3.0):
    system = tdacm.dual_paper_system()
    print(system.summary())
    for i, arm in enumerate(system.arms):
        print(
            f"rod {i}: strains q[{arm.strains.start}:{arm.strains.stop}], "
            f"tensions u[{arm.tensions.start}:{arm.tensions.stop}]"
        )
    hover = hover_stabilizer(system, tension=0.0)

    def u(t, q, qd):
        cmd = hover(t, q, qd)  # motors from the stabilizer, zero tensions
        if t >= 0.5:
            cmd[system.arms[0].tensions.start + 0] = 1.0  # rod 0, tendon on +y
            cmd[system.arms[1].tensions.start + 2] = 1.0  # rod 1, tendon on -y
        return cmd

    q0 = np.zeros(system.n)
    q0[5] = 3.0
    res = tdacm.simulate(system, q0, None, duration=duration, dt=2e-3, u=u, record_dt=0.05)
    tips = np.array([[system.tip_pose(q, r)[:3, 3] for r in range(system.n_rods)] for q in res.q])
    print(f"completed: {res.completed}; final drone position {res.q[-1, 3:6].round(4)}")
    for r in range(system.n_rods):
        print(f"tip {r}: start {tips[0, r].round(4)} -> end {tips[-1, r].round(4)} m")
    path = Path(out)
    path.mkdir(parents=True, exist_ok=True)
    np.savez(path / "dual.npz", t=res.t, q=res.q, qd=res.qd, u=res.u, tips=tips)
    print(f"written {path.resolve() / 'dual.npz'}")
    return res


if __name__ == "__main__":
    main()

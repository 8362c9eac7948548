"""Cost of contact in the plant step and of a closed loop in contact.  Run:
``python benchmarks/bench_contact.py`` (``--json`` for a machine-readable line).

1. One control period of the plant (:class:`tdacm.loop.plant.Plant`, the paper's floating
   TD-ACM in a bent, moving state at 3 m) without contact, and with contact on but not
   touching (the ground, the target's box and a cylinder, the rod 2 m above them): medians of
   interleaved repeats and their ratio (target: at most 1.10).
2. The same plant pressing its tip sphere on a plane (``contact_substeps`` RK4 steps per
   period): simulated seconds per wall-clock second of the plant alone.
3. The closed loop of ``paper-in-fov`` (analytic C_L, no C_G) whose tip lands on a sphere
   below its desired position: wall time per period far from it and while touching, and the
   real-time factor while touching (target: above 1).
4. The shipped ``touch-target`` run (seed 0): wall time per period approaching and holding
   0.3 N on the target's box (128 RK4 steps a period near it), and the real-time factors.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import tdacm
from tdacm.bench import batch_times
from tdacm.contact import Box, ContactModel, Cylinder, Plane
from tdacm.loop.plant import Plant
from tdacm.system.contact import contact_array, contact_state


def _median(fn, number, repeats):
    return float(np.median(batch_times(fn, number, repeats)))


def run(repeats: int = 11, number: int = 500, dt: float = 0.02) -> dict:
    s = tdacm.paper_system()
    q = np.zeros(s.n)
    q[3:6] = [0.1, -0.2, 3.0]
    q[6:] = [0.3, -0.2]
    qd = np.r_[0.05, -0.03, 0.01, 0.4, -0.2, 0.1, 0.5, 0.3]
    u = np.r_[np.full(4, 9.81 * s.total_mass / 4), 1.0, 0.5, 0.0, 0.2]
    scene = ContactModel(
        obstacles=(
            Plane((0, 0, 0)),
            Box((0, 0, 0.2), (0.4, 0.4, 0.4)),
            Cylinder((1.0, 0, 0.5), 0.1, 1.0),
        )
    )
    plain = Plant(s, q, qd)
    env = Plant(s, q, qd, contact=contact_array(s, scene))

    def step(p):
        def f():
            p.reset(q, qd)
            p.advance(u, dt)

        return f

    f_plain, f_env = step(plain), step(env)
    f_plain(), f_env()
    assert env.last_substeps == env.substeps  # far from the obstacles
    # the rod near the box, not touching: the in-kernel check runs
    near = Plant(s, q, qd, contact=contact_array(s, ContactModel(
        obstacles=(Box(tuple(s.tip_pose(q)[:3, 3] - [0, 0, 0.22]), (0.4, 0.4, 0.4)),))))  # fmt: skip
    near.advance(u, dt)
    t_near = _median(step(near), number, 3)
    near_touch = contact_state(s, near.state.q, near.state.qd, near.contact).clearance
    ts_plain, ts_env = [], []
    for _ in range(repeats):
        ts_plain.append(_median(f_plain, number, 1))
        ts_env.append(_median(f_env, number, 1))
    t_plain, t_env = float(np.median(ts_plain)), float(np.median(ts_env))
    # pressing: a plane 2 cm above the tip of the hovering, straight rod
    q2 = np.zeros(s.n)
    q2[5] = 3.0
    tip = s.tip_pose(q2)[:3, 3]
    press = ContactModel(obstacles=(Plane(tuple(tip - [0, 0, 0.0101])),))
    touch = Plant(s, q2, np.zeros(s.n), contact=contact_array(s, press))
    u2 = np.r_[np.full(4, 9.81 * s.total_mass / 4 - 0.02), 0.0, 0.0, 0.0, 0.0]
    periods = 100
    t0 = time.perf_counter()
    for _ in range(periods):
        touch.advance(u2, dt)
    wall = time.perf_counter() - t0
    st = contact_state(s, touch.state.q, touch.state.qd, touch.contact)
    return {
        "plant_period_s": t_plain,
        "plant_period_contact_far_s": t_env,
        "ratio_far": t_env / t_plain,
        "plant_period_near_s": t_near,
        "near_clearance_m": near_touch,
        "touching_real_time_factor": periods * dt / wall,
        "touching_substeps": touch.last_substeps,
        "touching_tip_force_N": float(np.linalg.norm(st.tip)),
    }


SCENE = """
extends = "paper-in-fov"
name = "contact-bench"
[[scene.obstacles]]
shape = "sphere"
position = [0.0, 0.0, 1.62]
radius = 0.3
[cameras]
local_renderer = "analytic"
global_every = 0
"""


def closed_loop(duration: float = 6.0) -> dict:
    import tempfile
    from pathlib import Path

    from tdacm.sim.assemble import build_loop
    from tdacm.sim.scenario import load_scenario

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "contact-bench.toml"
        path.write_text(SCENE)
        loop = build_loop(load_scenario(path)).loop
    loop.reset()
    far, near = [], []
    while loop.plant.state.t < duration:
        t0 = time.perf_counter()
        st = loop.step()
        (near if loop.plant.last_substeps > loop.plant.substeps else far).append(
            time.perf_counter() - t0
        )
        if st.done:
            break
    a = loop.log.arrays()
    f = np.linalg.norm(a["contact_tip"] + a["contact_rod"], axis=1)
    dt = loop.dt
    return {
        "loop_period_far_s": float(np.median(far)),
        "loop_period_touching_s": float(np.mean(near)),
        "loop_touching_periods": int((f > 0).sum()),
        "loop_touching_real_time_factor": dt / float(np.mean(near)),
        "loop_max_contact_force_N": float(f.max()),
    }


def touch_target() -> dict:
    """The shipped ``touch-target`` scenario (seed 0: the probe pressed on the target's box
    with 128 plant steps a period near it): wall time per period in each phase of the touch
    servo and the real-time factor of the hold."""
    from tdacm.sim.assemble import build_loop
    from tdacm.sim.scenario import load_scenario

    scenario = load_scenario("touch-target")
    loop = build_loop(scenario).loop
    nsteps = int(round(scenario.data["duration"] / loop.dt))
    loop.reset()
    walls = []
    for k in range(nsteps + 1):
        t0 = time.perf_counter()
        st = loop.step(last=k == nsteps)
        walls.append(time.perf_counter() - t0)
        if st.done:
            break
    phase = np.asarray(loop.log.arrays()["touch_phase"])
    walls = np.asarray(walls[: len(phase)])
    dt = loop.dt
    hold = walls[phase[: len(walls)] == 2]
    return {
        "touch_period_approach_s": float(np.median(walls[phase[: len(walls)] == 0])),
        "touch_period_hold_s": float(np.median(hold)),
        "touch_hold_real_time_factor": dt / float(np.mean(hold)),
        "touch_run_real_time_factor": loop.plant.state.t / float(walls.sum()),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    r = run()
    r.update(closed_loop())
    r.update(touch_target())
    if ap.parse_args().json:
        print(json.dumps(r))
        return
    print(f"plant period, no contact:          {1e6 * r['plant_period_s']:8.1f} us")
    print(f"plant period, contact not touching: {1e6 * r['plant_period_contact_far_s']:8.1f} us"
          f"  (ratio {r['ratio_far']:.3f}, target <= 1.10)")  # fmt: skip
    print(f"plant period, 1-2 cm from a box:    {1e6 * r['plant_period_near_s']:8.1f} us"
          f"  (clearance {100 * r['near_clearance_m']:.1f} cm, fine steps)")  # fmt: skip
    print(f"pressing ({r['touching_substeps']} RK4 steps a period, tip force "
          f"{r['touching_tip_force_N']:.3f} N): {r['touching_real_time_factor']:.1f}x real time")  # fmt: skip
    print(f"closed loop (analytic C_L, no C_G): {1e3 * r['loop_period_far_s']:.2f} ms a period far, "
          f"{1e3 * r['loop_period_touching_s']:.2f} ms near or touching "
          f"({r['loop_touching_periods']} periods in contact, up to "
          f"{r['loop_max_contact_force_N']:.2f} N): "
          f"{r['loop_touching_real_time_factor']:.1f}x real time")  # fmt: skip
    print(f"touch-target (128 steps a period at the box): {1e3 * r['touch_period_approach_s']:.2f} "
          f"ms a period approaching, {1e3 * r['touch_period_hold_s']:.2f} ms holding "
          f"({r['touch_hold_real_time_factor']:.1f}x real time), whole run "
          f"{r['touch_run_real_time_factor']:.1f}x real time")  # fmt: skip


if __name__ == "__main__":
    main()

"""A world-period's steps one at a time: each block step of world 0 of `paper-in-fov` in the
engine's configuration, called again and again in a compiled loop on the state a 2 s run left
(so its code and data stay in the core's caches), against the same period's halves in a run
(`tdacm.bench.batch.period_split`: every step's code and data as a run leaves them).

    python benchmarks/bench_period_parts.py [--calls 2000] [--worlds 64]

The loops compile at the first call (a few minutes, then cached next to this file). Prints us
a call (best and median of 3 rounds) and the halves in a run; docs/benchmarks.md, "Where a
period goes".
"""

import argparse
import os
import time

import numpy as np
from numba import njit

from tdacm._records import take, take_at
from tdacm.aero.wind import N_WIND_NORMALS
from tdacm.batch import engine as E
from tdacm.bench.batch import _batch, period_split
from tdacm.control.hierarchical import controller_step
from tdacm.loop.plant import plant_step
from tdacm.loop.servo import servo_command, servo_perceive
from tdacm.system.worlds import model_of_world


@njit(cache=True)
def plant_calls(model, data, calls):
    """`plant_step` over one period from world 0's state, ``calls`` times."""
    rw = take(model.robot, 0)
    mw = model_of_world(model.plant_model, rw)
    pp, pd = take(model.plant, 0), take(data.plant, 0)
    dn, wn = np.zeros(3), np.empty((0, N_WIND_NORMALS))
    acc = 0.0
    for _ in range(calls):
        plant_step(pp, pd, mw, data.q[0].copy(), data.qd[0].copy(), data.u[0], model.dt, 0.0,
                   10, dn, wn, data.q_next[0], data.qd_next[0], data.qdd_next[0])  # fmt: skip
        acc += data.q_next[0, 0]
    return acc


@njit(cache=True)
def controller_calls(model, data, calls):
    """`controller_step` at world 0's state and servo reference, ``calls`` times."""
    mc = model_of_world(model.control_model, take(model.robot, 0))
    lead, robot = take_at(data.servo, 0, 0), take(data.robot_out, 0)
    acc = 0.0
    for _ in range(calls):
        controller_step(take(model.controller, 0), take(data.controller, 0), mc, data.q[0],
                        data.qd[0], lead.q_d, lead.qd_d, robot.qdd_d, model.dt, data.u[0],
                        data.tau[0], data.q_ref[0], take(data.work, 0))  # fmt: skip
        acc += data.u[0, 0]
    return acc


@njit(cache=True)
def perceive_calls(model, data, calls):
    """`servo_perceive` of world 0's last frame, ``calls`` times."""
    mw = model_of_world(model.plant_model, take(model.robot, 0))
    n = data.q.shape[1]
    f = take_at(data.frame, 0, 0)
    acc = 0.0
    for _ in range(calls):
        servo_perceive(take_at(model.servo, 0, 0), take_at(data.servo, 0, 0), mw, 0.2, model.dt,
                       10, data.q[0], np.zeros((n, n)), f.found[0], f.uv, f.xy, f.z,
                       f.capture[0], take_at(data.servo_out, 0, 0))  # fmt: skip
        acc += data.servo_out.rmse[0, 0, 0]
    return acc


@njit(cache=True)
def command_calls(model, data, calls):
    """`servo_command` of world 0's view (C_G not offered), ``calls`` times."""
    mw = model_of_world(model.plant_model, take(model.robot, 0))
    m_count = model.global_sensor.corners.shape[2]
    corners, seen = np.zeros((m_count, 4, 2)), np.zeros(m_count, np.bool_)
    acc = 0.0
    for _ in range(calls):
        servo_command(take_at(model.servo, 0, 0), take_at(data.servo, 0, 0), mw, 0.2, model.dt,
                      data.q[0], False, np.full(6, np.nan), False, corners, seen,
                      take_at(data.servo_out, 0, 0))  # fmt: skip
        acc += data.servo_out.twist[0, 0, 0]
    return acc


@njit(cache=True)
def act_steps_in_turn(model, data, calls):
    """`servo_command`, `controller_step` and `plant_step` of world 0 one after the other,
    ``calls`` times (each of the loops above for one call, so each call also pays its loop's
    set-up: a few record views and the state's copy): the act half's three steps with their
    code in turn, as in a run, on one world's state that stays put."""
    acc = 0.0
    for _ in range(calls):
        acc += command_calls(model, data, 1)
        acc += controller_calls(model, data, 1)
        acc += plant_calls(model, data, 1)
    return acc


@njit(cache=True)
def sense_calls(model, data, calls):
    """The engine's whole `sense` of world 0 (the frame, perception, `servo_perceive`)."""
    for _ in range(calls):
        E.sense(model, data, 0)
    return 0.0


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--calls", type=int, default=2000)
    p.add_argument("--worlds", type=int, default=64)
    a = p.parse_args()
    b = _batch(4, 1, 2.0)
    b.run()  # the worlds as a 2 s run leaves them
    steps = (
        ("plant_step", plant_calls),
        ("controller_step", controller_calls),
        ("servo_perceive", perceive_calls),
        ("servo_command", command_calls),
        ("the three act steps in turn (servo_command, controller, plant)", act_steps_in_turn),
        ("sense (the engine's, servo_perceive included)", sense_calls),
    )
    for name, fn in steps:
        fn(b.model, b.data, 2)  # compiles on a cold cache
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            fn(b.model, b.data, a.calls)
            times.append(1e6 * (time.perf_counter() - t0) / a.calls)
        times.sort()
        print(f"{name:64s} {times[0]:7.1f} us a call (median {times[1]:.1f}), "
              f"load {os.getloadavg()[0]:.1f}", flush=True)  # fmt: skip
    res = period_split(a.worlds)
    print(f"in a run ({a.worlds} worlds, one thread): act {res['act_us']:.1f} us, sense "
          f"{res['sense_us']:.1f} us, the period {res['period_us']:.1f} us a world, "
          f"load {res['load'][0]:.1f}")  # fmt: skip

"""Fuzzing the closed loop: random robots, sensors, initial states and actions, short episodes.

Every state the plant, the cameras, the estimator or the servo can reach must end an episode
with a named :class:`~tdacm.loop.Termination` (or let it run to its end); an exception is a
bug. :func:`fuzz` draws ``n`` episodes from a seed and returns one :class:`FuzzOutcome` each;
:func:`count` tallies them by termination. The test suite runs a few dozen
(tests/campaign/test_fuzz.py), ``benchmarks/fuzz.py`` thousands.

One *case* is a loop assembled from a shipped scenario (the flying ``paper-in-fov`` or the
held ``ground-test-a``) with random overrides:

* the robot within ranges around the paper's values (``[robot.rod]``, ``[robot.tendons]``,
  ``[robot.drone]``, ``[robot.attachment]``);
* C_L analytic or rendered (``cameras.local_renderer``), C_G planar;
* ``sensors.pixel_noise`` in [0, 200] px, ``dropout`` in [0, 0.9], ``latency_steps`` in
  [0, 10];
* the state true or estimated (``estimation.source``);

and runs :data:`EPISODES_PER_CASE` episodes on it, each from a random initial state
(:meth:`~tdacm.loop.ClosedLoop.reset`), its run summary computed at the end as ``tdacm run``
writes it, under one policy: the loop's own servo and controller,
random twists (``ClosedLoop.act(sensed, twist=...)``), random actuator inputs
(``act(sensed, u=...)``, up to 1.5 times the limits), or either of these with a non-finite
value injected at a random period. A case whose overrides the scenario checks reject (an
invalid input: ``tdacm run`` exits 2) is counted as ``rejected`` and has no episodes; one whose
assembly raises anything else is an ``exception`` (a bug), and the campaign goes on.
"""

from __future__ import annotations

import json
import logging
import traceback
from collections import Counter
from dataclasses import dataclass

import numpy as np

from .. import paper_values as PV
from ..sim import ScenarioError
from ..sim.assemble import build_loop
from ..sim.runner import Simulation
from ..sim.scenario import load_scenario

log = logging.getLogger(__name__)

#: episodes run on one assembled loop (each from its own initial state and policy)
EPISODES_PER_CASE = 3
POLICIES = ("servo", "twist", "actuators", "twist-nonfinite", "actuators-nonfinite")
#: the name counted for an episode that ran to its end
COMPLETED = "completed"
REJECTED = "rejected"


@dataclass(frozen=True)
class FuzzOutcome:
    """One episode: its case and policy, how it ended (a :class:`~tdacm.loop.Termination`
    value, :data:`COMPLETED`, :data:`REJECTED` for a case the checks refused, or ``"exception"``
    with the traceback in ``error``) and the periods it ran."""

    case: int
    episode: int
    scenario: str
    policy: str
    outcome: str
    reason: str | None
    steps: int
    overrides: dict
    error: str | None = None


def _scale(rng, lo, hi) -> float:
    """A factor drawn log-uniformly in ``[lo, hi]``."""
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw_case(rng: np.random.Generator) -> tuple[str, dict]:
    """``(scenario name, overrides)`` of one random case (module docstring)."""
    name = "paper-in-fov" if rng.random() < 0.6 else "ground-test-a"
    robot = {
        "rod": {
            "length": PV.ROD_LENGTH * _scale(rng, 0.7, 1.4),
            "diameter": PV.ROD_DIAMETER * _scale(rng, 0.8, 1.25),
            "density": PV.ROD_DENSITY * _scale(rng, 0.7, 1.4),
            "youngs_modulus": PV.ROD_YOUNGS_MODULUS * _scale(rng, 0.5, 2.0),
            "damping": PV.ROD_DAMPING * _scale(rng, 0.5, 2.0),
            "tip_mass": PV.TIP_MASS * _scale(rng, 0.5, 2.0),
        },
        "tendons": {
            "radius": PV.TENDON_RADIUS * _scale(rng, 0.7, 1.4),
            "max_tension": PV.TENDON_MAX_TENSION * _scale(rng, 0.5, 2.0),
        },
        "attachment": {"offset": PV.ATTACHMENT_OFFSET * _scale(rng, 0.5, 2.0)},
    }
    if name == "paper-in-fov":
        robot["drone"] = {
            "mass": PV.DRONE_MASS * _scale(rng, 0.7, 1.4),
            "max_thrust": PV.DRONE_MAX_THRUST * _scale(rng, 0.8, 2.0),
        }
    over = {
        "robot": robot,
        "cameras": {
            "local_renderer": "analytic" if rng.random() < 0.5 else "planar",
            "global_renderer": "planar",
            "global_every": 0,
        },
        "sensors": {
            "pixel_noise": float(rng.choice([0.0, rng.uniform(0, 5), rng.uniform(0, 200)])),
            "dropout": float(rng.choice([0.0, rng.uniform(0, 0.9)])),
            "latency_steps": int(rng.integers(0, 11)),
        },
        "estimation": {"source": "estimated" if rng.random() < 0.3 else "true"},
        "seed": int(rng.integers(0, 2**31)),
    }
    return name, over


def _initial_state(rng, q0: np.ndarray, floating: bool) -> tuple[np.ndarray, np.ndarray]:
    q = q0.copy()
    n = len(q)
    ns = n - (6 if floating else 0)
    q[n - ns :] += rng.uniform(-0.6, 0.6, ns)
    qd = np.zeros(n)
    if floating:
        q[:3] += rng.uniform(-0.6, 0.6, 3)  # roll, pitch, yaw
        q[3:6] += rng.uniform(-0.5, 0.5, 3)
        qd[:] = rng.normal(0.0, 0.3, n)
    else:
        qd[:] = rng.normal(0.0, 0.3, n)
    return q, qd


def _actuator_limits(system) -> np.ndarray:
    hi = np.concatenate([np.full(a.tendons.n, a.tendons.max_tension) for a in system.arms])
    if system.floating:
        hi = np.concatenate([np.full(4, system.base.max_thrust), hi])
    return hi


def run_episode(loop, rng: np.random.Generator, policy: str, duration: float) -> tuple:
    """One episode of ``policy`` on an assembled loop already reset: ``(termination or
    None, reason, steps)``."""
    nsteps = int(round(duration / loop.dt))
    hi = _actuator_limits(loop.plant.system)
    sigma = float(rng.choice([0.05, 0.5, 3.0]))
    bad_step = int(rng.integers(0, nsteps + 1)) if policy.endswith("nonfinite") else -1
    bad = float(rng.choice([np.nan, np.inf, -np.inf]))
    twist = u = None
    for k in range(nsteps + 1):
        sensed = loop.sense()
        if policy.startswith("twist"):
            twist = rng.normal(0.0, sigma, 6)
            if k == bad_step:
                twist[rng.integers(0, 6)] = bad
        elif policy.startswith("actuators"):
            u = rng.uniform(0.0, 1.5, len(hi)) * hi
            if k == bad_step:
                u[rng.integers(0, len(u))] = bad
        st = loop.act(sensed, twist=twist, u=u, last=k == nsteps)
        if st.done:
            return st.termination, st.reason, k + 1
    return None, None, nsteps + 1


def _summarize(scenario, assembly, duration, termination, reason) -> dict:
    """The run summary of the episode just run, as ``tdacm run`` writes it (it must exist, and
    be JSON, whatever state the episode ended in)."""
    from ..loop.closed_loop import RunResult

    loop = assembly.loop
    result = RunResult(loop.log.arrays(), [], termination is not None, reason, 0.0,
                       loop.switch_time, loop.plan, False, termination)  # fmt: skip
    summary = Simulation(scenario, duration=duration).summary(assembly, result)
    json.dumps(summary, allow_nan=True)
    return summary


def fuzz(n: int, seed: int = 0, duration=(0.5, 1.0), progress=None) -> list[FuzzOutcome]:
    """At least ``n`` episodes (whole cases of :data:`EPISODES_PER_CASE`) drawn from ``seed``;
    rejected cases are reported and do not count. ``progress(outcomes)`` is called after each
    case."""
    rng = np.random.default_rng(seed)
    out: list[FuzzOutcome] = []
    done = 0
    case = 0
    while done < n:
        name, over = draw_case(rng)
        try:
            sc = load_scenario(name).with_overrides(over, "fuzz")
            assembly = build_loop(sc)
        except ScenarioError as exc:  # invalid input: `tdacm run` exits 2
            out.append(FuzzOutcome(case, -1, name, "-", REJECTED, str(exc), 0, over))
            case += 1
            continue
        except Exception:  # a bug in building: reported, and the campaign goes on
            out.append(FuzzOutcome(case, -1, name, "-", "exception", None, 0, over,
                                   traceback.format_exc()))  # fmt: skip
            case += 1
            continue
        loop = assembly.loop
        world = assembly.world
        try:
            for e in range(EPISODES_PER_CASE):
                policy = POLICIES[int(rng.integers(0, len(POLICIES)))]
                q0, qd0 = _initial_state(rng, world.q0, loop.plant.system.floating)
                dur = float(rng.uniform(*duration))
                try:
                    loop.reset(q0, qd0)
                    term, reason, steps = run_episode(loop, rng, policy, dur)
                    _summarize(sc, assembly, dur, term, reason)
                except Exception:  # a bug: reported with its traceback, never hidden
                    out.append(FuzzOutcome(case, e, name, policy, "exception", None, 0, over,
                                           traceback.format_exc()))  # fmt: skip
                else:
                    outcome = COMPLETED if term is None else str(term)
                    out.append(FuzzOutcome(case, e, name, policy, outcome, reason, steps, over))
                done += 1
        finally:
            loop.close()
        case += 1
        if progress is not None:
            progress(out)
    return out


def count(outcomes) -> dict:
    """``{outcome: episodes}`` (rejected cases counted apart), most frequent first."""
    return dict(Counter(o.outcome for o in outcomes).most_common())


def main_report(outcomes, wall: float) -> str:
    """A plain-text report: the counts, the rate, the first traceback of each exception kind."""
    eps = [o for o in outcomes if o.outcome != REJECTED]
    lines = [f"{len(eps)} episodes ({len(outcomes) - len(eps)} rejected cases) in {wall:.0f} s "
             f"({len(eps) / max(wall, 1e-9):.2f} episodes/s)"]  # fmt: skip
    for k, v in count(outcomes).items():
        lines.append(f"  {k:20s} {v}")
    seen = set()
    for o in outcomes:
        if o.error and o.error.splitlines()[-1] not in seen:
            seen.add(o.error.splitlines()[-1])
            lines.append(f"\ncase {o.case} episode {o.episode} ({o.scenario}, {o.policy}):")
            lines.append(o.error)
    return "\n".join(lines)

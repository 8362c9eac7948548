"""Per-period observers of a run (``ClosedLoop.run(..., on_step=...)``): :class:`LiveRun`
publishes each period to a :class:`~.server.LiveServer`, :class:`RealTime` paces the run to
the wall clock; :func:`chain` calls several. An observer reads the loop and sleeps; it never
writes to the loop, so a run gives the same results with or without them."""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from .messages import ROW_SERIES

log = logging.getLogger(__name__)

#: How far (s) the simulation may fall behind the wall clock under :class:`RealTime` before
#: it says so (once): a slower machine, not a passing hiccup.
LAG_NOTICE_S = 0.25

_NAN4 = np.full((4, 2), np.nan)


def chain(*observers):
    """One ``on_step`` calling each of ``observers`` (``None`` skipped) in order; ``None`` if
    there is none."""
    obs = [o for o in observers if o is not None]
    if not obs:
        return None
    if len(obs) == 1:
        return obs[0]

    def on_step(step):
        for o in obs:
            o(step)

    return on_step


class RealTime:
    """Paces a run of control period ``dt`` so that simulated time goes no faster than
    ``speed`` times the wall clock: after each period it sleeps until the wall clock reaches
    the next period's start. A run slower than that stays slower (nothing is skipped); when
    it falls :data:`LAG_NOTICE_S` behind, one warning says so (:attr:`lagging`)."""

    def __init__(
        self,
        dt: float,
        speed: float = 1.0,
        lag_notice_s: float = LAG_NOTICE_S,
        label: str = "--realtime",
    ):
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be a finite positive number, got {speed!r}")
        self.dt, self.speed, self.lag_notice_s = float(dt), float(speed), float(lag_notice_s)
        self.label = label
        self._wall0 = self._t0 = None
        #: the largest lag behind the wall clock so far (s)
        self.max_lag = 0.0
        self.lagging = False

    def slack(self, t_next: float) -> float | None:
        """How long (s) until simulated time ``t_next`` is due on the wall clock (negative:
        behind); ``None`` before the clock starts."""
        if self._wall0 is None:
            return None
        return self._wall0 + (float(t_next) - self._t0) / self.speed - time.perf_counter()

    def start(self, t: float) -> None:
        """Start the clock: simulated time ``t`` is now."""
        self._wall0, self._t0 = time.perf_counter(), float(t)

    def wait(self, t_next: float) -> None:
        """Sleep until simulated time ``t_next`` is due on the wall clock (the first call
        starts the clock at ``t_next``)."""
        if self._wall0 is None:
            self.start(t_next)
            return
        now = time.perf_counter()
        due = self._wall0 + (float(t_next) - self._t0) / self.speed
        if due > now:
            time.sleep(due - now)
            return
        lag = now - due
        self.max_lag = max(self.max_lag, lag)
        if lag > self.lag_notice_s and not self.lagging:
            self.lagging = True
            log.warning(
                "%s: slower than %sreal time (%.2f s behind at t = %.2f s); it goes on as "
                "fast as it can",
                self.label,
                "" if self.speed == 1 else f"{self.speed:g} x ",
                lag,
                float(t_next),
            )

    def __call__(self, step) -> None:
        if self._wall0 is None:  # the first period started about now
            self.start(step.t)
        if not step.done:
            self.wait(step.t + self.dt)


def row_of_log(rows: dict) -> dict:
    """The last row of a :class:`~tdacm.loop.logger.RunLog`'s ``rows`` (the series of
    :data:`~.messages.ROW_SERIES` it has)."""
    return {k: rows[k][-1] for k in ROW_SERIES if rows.get(k)}


def row_of_step(state, step) -> dict:
    """The row of a period from the plant state it started from (``state``, a
    :class:`~tdacm.loop.data.PlantState`) and what it produced (``step``, a
    :class:`~tdacm.loop.closed_loop.LoopStep`): the values a :class:`~tdacm.loop.logger.RunLog`
    records, for a loop that keeps no log (the Gymnasium env)."""
    view, cmd, act = step.view, step.command, step.actuation
    row = {
        "t": state.t,
        "q": state.q,
        "qd": state.qd,
        "u": act.u,
        "tau": act.tau,
        "features": cmd.features,
        "feature_error": cmd.error,
        "points_local": view.points if view.found else _NAN4,
        "rmse": cmd.rmse,
    }
    arms = getattr(view, "arms", ())
    if arms:
        row["points_local_arms"] = np.array([v.points if v.found else _NAN4 for v in arms])
    return row


class LiveRun:
    """Publishes a :class:`~tdacm.loop.ClosedLoop`'s run to ``server`` as it goes (an
    ``on_step`` observer): each period's row of the loop's log, at the server's rate and
    share, the last one always; and the progress (``duration``: the run's, for the fraction
    done). With ``pace`` (the run's :class:`RealTime`, chained after this observer), steps also
    go out in the time the pace would sleep (:meth:`~.server.LiveServer.due`'s ``slack``)."""

    def __init__(self, server, loop, duration: float, scenario: str = "", pace=None):
        self.server, self.loop, self.pace = server, loop, pace
        self.duration, self.scenario = float(duration), str(scenario)
        self._n = 0
        self._steps = 0
        self._wall0 = None

    def __call__(self, step) -> None:
        if self._wall0 is None:
            self._wall0 = time.perf_counter()
        self._steps += 1
        server = self.server
        pace = self.pace
        slack = None if pace is None else pace.slack(step.t + pace.dt)
        if not (step.done or server.due(slack=slack)):
            return
        rows = self.loop.log.rows
        n = len(rows["t"])
        if n > self._n:  # the period was logged (a period that ended the run early is not)
            self._n = n
            server.publish(rows["t"][-1], row_of_log(rows), final=step.done, slack=slack)
        self._progress(step.t, "running" if not step.done else self._state(step))

    @staticmethod
    def _state(step) -> str:
        return "done" if step.reason is None else "ended early"

    def _progress(self, t: float, state: str, reason: str | None = None) -> None:
        wall = time.perf_counter() - (self._wall0 or time.perf_counter())
        self.server.progress(
            scenario=self.scenario,
            t=float(t),
            duration=self.duration,
            fraction=float(t) / self.duration if self.duration > 0 else 1.0,
            step=self._steps,
            wall_time=wall,
            speed=float(t) / wall if wall > 0 else 0.0,
            state=state,
            reason=reason,
        )

    def finish(self, result) -> None:
        """The last progress message of a finished run (a :class:`~tdacm.loop.RunResult`)."""
        t = result.arrays["t"]
        end = float(t[-1]) if len(t) else 0.0
        state = "interrupted" if result.interrupted else (
            "ended early" if result.terminated else "done")  # fmt: skip
        self._progress(end, state, result.reason)

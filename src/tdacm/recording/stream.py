"""Stream a stored ``tdacm run`` folder to a live Foxglove server (``tdacm replay RUN --live``):
the messages of its MCAP export (:mod:`.export`, the same builders), step by step at the pace
of the simulated time."""

from __future__ import annotations

import time

import numpy as np

from ..live import RealTime
from .export import DEFAULT_SECTIONS, load_run_folder, messages_of, step_row

#: How often (s) :func:`stream_run` looks for a first client while it waits.
_POLL_S = 0.05


def stream_run(
    run_dir,
    server,
    *,
    speed: float = 1.0,
    wait: bool = True,
    n_sections: int = DEFAULT_SECTIONS,
    on_wait=None,
) -> int:
    """Send the run folder ``run_dir`` to ``server`` (a :class:`~tdacm.live.LiveServer`):
    its static topics, then each step at ``speed`` times the simulated time's pace (the
    server's rate decides which steps go out; the last one always does). With ``wait``, the
    steps start once a client subscribes (``on_wait()`` is called once before waiting).
    Returns the number of steps streamed. Raises :class:`~.export.ExportError` for a folder
    that cannot be read."""
    run = load_run_folder(run_dir)
    a = run.arrays
    t = np.asarray(a["t"], float)
    arrays = dict(a)
    for key in ("q", "qd", "tau", "u"):
        if key in arrays:
            arrays[key] = np.asarray(arrays[key], float).reshape(len(t), -1)
    server.attach(messages_of(run, n_sections))
    if wait and not server.subscribed():
        if on_wait is not None:
            on_wait()
        while not server.subscribed():
            time.sleep(_POLL_S)
        time.sleep(5 * _POLL_S)  # the client's other subscriptions follow its first one
    pace = RealTime(float(run.scenario.config.dt), speed, label="replay --live")
    duration = float(t[-1]) if len(t) else 0.0
    wall0 = time.perf_counter()
    for k in range(len(t)):
        pace.wait(t[k])
        last = k == len(t) - 1
        slack = None if last else pace.slack(t[k + 1])  # until the next step is due
        if server.publish(t[k], step_row(arrays, k), final=last, slack=slack) or last:
            wall = time.perf_counter() - wall0
            server.progress(
                scenario=str(run.summary.get("scenario", "")),
                t=float(t[k]),
                duration=duration,
                fraction=float(t[k]) / duration if duration > 0 else 1.0,
                step=k + 1,
                wall_time=wall,
                speed=float(t[k]) / wall if wall > 0 else 0.0,
                state="done" if last else "running",
                reason=None,
            )
    return len(t)

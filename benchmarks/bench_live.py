"""Watching live: the cost of ``tdacm run --live`` with one client, and ``--realtime``'s pace.

    python benchmarks/bench_live.py [--scenario paper-in-fov] [--duration 5] [--repeats 5] [--out out/bench]

Overhead: the same command with and without ``--live PORT``, alternated ``--repeats`` times,
with a client (:class:`tdacm.live.client.FoxgloveClient`, in this process) subscribed to every
topic the server advertises (the images too: the most a client can ask for); the figure is the
median of the closed loop's wall time (the summary's ``wall_time_s``) with the server over the
median without, minus one; the commands' CPU time (the run process and its threads) is
recorded too, a measure of the work added that the other processes' load disturbs less. Real time: ``--realtime`` runs of ``--duration`` s (alone, and with
``--live`` and the client), their loop's wall time against the duration. Each command runs in a
new process (``python -m tdacm.cli``); the load average is recorded before and after.

Writes ``OUT/live.json`` and prints it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from tdacm.live.client import FoxgloveClient, free_port


def _run(scenario: str, duration: float, out: Path, *flags) -> dict:
    """``tdacm -q run SCENARIO --duration D --out OUT FLAGS``; its summary and the command's
    own wall time."""
    t0 = time.perf_counter()
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cmd = [sys.executable, "-m", "tdacm.cli", "-q", "run", scenario, "--duration",
           str(duration), "--out", str(out), *flags]  # fmt: skip
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    if p.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(cmd)} exited {p.returncode}: {p.stderr}")
    summary = json.loads((out / "summary.json").read_text())
    return {"loop_wall_s": summary["wall_time_s"], "command_wall_s": wall, "command_cpu_s": cpu}


def _watched(scenario: str, duration: float, out: Path, *flags) -> dict:
    """:func:`_run` with ``--live PORT`` and a client subscribed to every advertised topic."""
    port = free_port()
    got: dict = {}

    def watch():
        client = FoxgloveClient(port)
        client.wait_for(lambda: "/tdacm/progress" in client.channels, 600)
        client.subscribe(sorted(client.channels))
        client.wait_for(lambda: False, 3600)  # until the server stops
        got.update(messages={t: len(m) for t, m in client.messages.items()})

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    res = _run(scenario, duration, out, "--live", str(port), *flags)
    th.join(timeout=30)
    res["messages"] = got.get("messages", {})
    return res


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--scenario", default="paper-in-fov")
    p.add_argument("--duration", type=float, default=5.0)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--out", default="out/bench")
    a = p.parse_args()
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        _run(a.scenario, 0.2, tmp / "warm")  # numba's cache loaded once before timing
        plain, live = [], []
        for i in range(a.repeats):  # alternated: a change of load hits both alike
            plain.append(_run(a.scenario, a.duration, tmp / f"plain{i}"))
            live.append(_watched(a.scenario, a.duration, tmp / f"live{i}"))
        realtime, realtime_live = [], []
        for i in range(a.repeats):
            realtime.append(_run(a.scenario, a.duration, tmp / f"rt{i}", "--realtime"))
            realtime_live.append(_watched(a.scenario, a.duration, tmp / f"rtl{i}", "--realtime"))
    load1 = os.getloadavg()

    def med(rows, key="loop_wall_s"):
        return statistics.median(r[key] for r in rows)

    res = {
        "scenario": a.scenario,
        "duration_s": a.duration,
        "repeats": a.repeats,
        "cores": os.cpu_count(),
        "loadavg_before": load0,
        "loadavg_after": load1,
        "loop_wall_s_plain": [r["loop_wall_s"] for r in plain],
        "loop_wall_s_live": [r["loop_wall_s"] for r in live],
        "median_plain_s": med(plain),
        "median_live_s": med(live),
        "live_overhead": med(live) / med(plain) - 1.0,
        # the whole command's CPU (the run, its figures, the server's threads): the work added,
        # less sensitive to the load of other processes than the wall time
        "command_cpu_s_plain": [r["command_cpu_s"] for r in plain],
        "command_cpu_s_live": [r["command_cpu_s"] for r in live],
        "cpu_overhead_s": med(live, "command_cpu_s") - med(plain, "command_cpu_s"),
        "messages_received_last_live_run": live[-1]["messages"],
        "realtime_loop_wall_s": [r["loop_wall_s"] for r in realtime],
        "realtime_error": med(realtime) / a.duration - 1.0,
        "realtime_live_loop_wall_s": [r["loop_wall_s"] for r in realtime_live],
        "realtime_live_error": med(realtime_live) / a.duration - 1.0,
    }
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "live.json").write_text(json.dumps(res, indent=2))
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()

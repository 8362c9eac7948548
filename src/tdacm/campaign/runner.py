"""Running a campaign on Dask, streaming one Parquet row per run, resumable.

The store is a directory ``OUT/results/`` of one-row Parquet files ``run-000042.parquet``, all
with the fixed schema :data:`ROW_SCHEMA` (so the directory is one Parquet dataset:
``pandas.read_parquet(OUT / "results")`` reads it as one table; :func:`~tdacm.campaign.store.read_results` does the
same sorted by run and also reads stores of older versions).  Only the
driver writes, each row to a temporary name renamed atomically, so an interrupted campaign
holds complete rows only; on restart the runs already stored are skipped and the missing ones
run, so no run is lost or run twice.  A run that raises is stored with ``status = "error"`` and
its traceback; the campaign goes on.

Runs execute on a Dask cluster: a ``LocalCluster`` of ``workers`` processes by default, or the
scheduler at ``scheduler`` (``tcp://host:port``) with no code change.  Each run is a pure
function of ``(spec, index, seed)``, so the same spec gives the same rows on any cluster.

On the batched engine (the spec's ``batched``, :mod:`tdacm.campaign.batched`) a Dask task is a
chunk of runs, one batch of worlds; its rows are stored as they come, like single runs.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
import traceback
from pathlib import Path

from .._extras import require
from .batched import CHUNK, execute_chunk, refusal
from .report import write_report
from .spec import (
    CampaignSpec,
    CampaignSpecError,
    load_spec,
    sample_overrides,
    succeeded,
    to_toml,
)
from .store import ROW_FIELDS, completed_runs, write_row


def execute_run(spec_dict: dict, index: int, seed: int) -> dict:
    """One campaign run (executed on a worker); never raises: errors become a row."""
    from ..sim.runner import Simulation
    from ..sim.scenario import load_scenario

    spec = CampaignSpec(**spec_dict)
    row = {"run": int(index), "seed": int(seed), "status": "ok", "error": ""}
    t0 = time.perf_counter()
    try:
        base = load_scenario(spec.scenario)
        overrides = sample_overrides(spec, base.data, seed)
        row["overrides"] = json.dumps(overrides, sort_keys=True)
        scenario = base.with_overrides(overrides, f"campaign run {index}")
        arrays, summary = Simulation(scenario, duration=spec.duration, seed=int(seed)).run(None)
        for k in ROW_FIELDS:
            row[k] = summary.get(k)
        row["success"] = succeeded(spec, arrays, summary)
    except Exception as exc:  # a failing run is data, not the end of the campaign
        row["status"] = "error"
        row["error"] = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=8)}"
        row["success"] = False
        row.setdefault("overrides", "")
    row["run_wall_s"] = time.perf_counter() - t0
    return row


def use_batched(spec: CampaignSpec) -> bool:
    """Whether ``spec`` runs on the batched engine: ``batched = true`` where the engine runs
    it (else a :class:`CampaignSpecError` naming the key and the refusal), ``"auto"`` where
    it runs it (else the block loop, with a one-line notice saying why), ``false`` never."""
    if spec.batched is False:
        return False
    why = refusal(spec)
    if why is None:
        return True
    if spec.batched is True:
        raise CampaignSpecError(f"{spec.source}: batched = true: {why}")
    logging.getLogger("tdacm.campaign").info(f"campaign: on the block loop, not batched: {why}")
    return False


def _chunks(todo: list[int], workers: int) -> list[list[int]]:
    """The runs ``todo`` in chunks of at most :data:`CHUNK`, at least two per worker while
    there are runs enough (the workers stay busy to the end)."""
    if not todo:
        return []
    k = max(1, min(CHUNK, -(-len(todo) // (2 * max(1, workers)))))
    return [todo[i : i + k] for i in range(0, len(todo), k)]


def _silence_distributed() -> None:
    import logging

    for name in ("distributed", "distributed.nanny", "distributed.worker", "tornado"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _prepare_out(spec: CampaignSpec, out: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    store = out / "results"
    store.mkdir(exist_ok=True)
    (out / "configs").mkdir(exist_ok=True)
    meta = out / "campaign.json"
    info = {"fingerprint": spec.fingerprint(), "spec": spec.as_dict()}
    if meta.exists():
        old = json.loads(meta.read_text())
        if old.get("fingerprint") != info["fingerprint"]:
            raise CampaignSpecError(
                f"{out} holds a campaign of a different spec (fingerprint {old.get('fingerprint')} "
                f"vs {info['fingerprint']}); use another --out or delete it"
            )
    else:
        meta.write_text(json.dumps(info, indent=2))
    for tmp in [*store.glob("*.tmp"), *store.glob(".*.tmp")]:
        tmp.unlink()  # a row interrupted mid-write: its run is redone
    return store


#: s: how long a campaign waits for the Dask scheduler named by ``scheduler`` to answer
SCHEDULER_TIMEOUT_S = 5.0


def _check_scheduler_address(address: str) -> None:
    """A ``CampaignSpecError`` naming ``--scheduler`` unless ``address`` reads as a Dask
    address (``tcp://host:port``; a bare ``host:port`` is TCP)."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, loc = parse_address(address)
        if scheme in ("tcp", "tls"):
            parse_host_port(loc)
    except ValueError as exc:
        raise CampaignSpecError(
            f"--scheduler {address!r} is not a Dask scheduler address (tcp://host:port): {exc}"
        ) from None


def _connect(Client, address: str):
    """A client of the scheduler at ``address``, or a ``CampaignSpecError`` naming
    ``--scheduler`` when none answers within :data:`SCHEDULER_TIMEOUT_S`."""
    try:
        return Client(address, timeout=SCHEDULER_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        raise CampaignSpecError(
            f"--scheduler {address}: no Dask scheduler answered within "
            f"{SCHEDULER_TIMEOUT_S:g} s ({type(exc).__name__})"
        ) from None


def run_campaign(
    spec_or_path,
    out,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    max_runs: int | None = None,
) -> dict:
    """Run (or resume) a campaign; returns the report (see :mod:`tdacm.campaign.report`).

    ``max_runs`` stops after that many new runs (used to test interruption)."""
    distributed = require("dask.distributed", "campaign")
    require("pandas", "campaign")
    require("pyarrow.parquet", "campaign")
    Client, LocalCluster = distributed.Client, distributed.LocalCluster
    as_completed = distributed.as_completed

    from ..sim.scenario import load_scenario

    if scheduler:
        _check_scheduler_address(scheduler)
    spec = load_spec(spec_or_path) if not isinstance(spec_or_path, CampaignSpec) else spec_or_path
    out = Path(out)
    store = _prepare_out(spec, out)
    seeds = spec.run_seeds()
    base = load_scenario(spec.scenario)
    todo = [i for i in range(spec.runs) if i not in completed_runs(store)]
    if max_runs is not None:
        todo = todo[:max_runs]
    for (
        i
    ) in todo:  # per-run replay files: `tdacm run SCENARIO --config configs/run-i.toml --seed s`
        cfg = sample_overrides(spec, base.data, int(seeds[i]))
        (out / "configs" / f"run-{i:06d}.toml").write_text(to_toml(cfg))
    done_before = spec.runs - len([i for i in range(spec.runs) if i not in completed_runs(store)])
    stored = 0
    if done_before:  # a resumed campaign: what the folder holds and what runs now
        logging.getLogger("tdacm.campaign").info(
            "campaign: %d of %d runs already stored in %s; %s",
            done_before, spec.runs, store,
            f"running the other {len(todo)}" if todo else "nothing to run, the report is rewritten",
        )  # fmt: skip
    batched = False
    if todo:
        cluster = None
        n = workers or max(1, (os.cpu_count() or 1))
        if scheduler:
            client = _connect(Client, scheduler)
            n = max(1, len(client.scheduler_info().get("workers", {})))
            try:  # after the scheduler answered: a refused --scheduler is the one line
                batched = use_batched(spec)
            except CampaignSpecError:
                client.close()
                raise
        else:
            batched = use_batched(spec)
            if int(n) < 1:
                raise CampaignSpecError(f"--workers must be >= 1, got {n}")
            # the worker processes ignore SIGINT (inherited across exec): Ctrl-C reaches the
            # driver only, which stops cleanly (no traceback per worker); stored rows are kept
            old = signal.signal(signal.SIGINT, signal.SIG_IGN) if _main_thread() else None
            try:
                cluster = LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None
                )
            finally:
                if old is not None:
                    signal.signal(signal.SIGINT, old)
            client = Client(cluster)
        bar = None
        if progress:
            from .._log import Progress

            bar = Progress(spec.runs, f"campaign {spec.scenario}", "run", initial=done_before)
        try:
            spec_dict = {k: v for k, v in spec.__dict__.items()}
            if batched:
                chunks = _chunks(todo, int(n))
                futures = [
                    client.submit(execute_chunk, spec_dict, c, [int(seeds[i]) for i in c],
                                  pure=False, key=f"chunk-{c[0]}-{c[-1]}-{seeds[c[0]]}")
                    for c in chunks
                ]  # fmt: skip
                runs_of = {f.key: c for f, c in zip(futures, chunks, strict=True)}
            else:
                futures = [
                    client.submit(
                        execute_run, spec_dict, i, int(seeds[i]), pure=False,
                        key=f"run-{i}-{seeds[i]}",
                    )
                    for i in todo
                ]  # fmt: skip
                runs_of = {f.key: [i] for f, i in zip(futures, todo, strict=True)}
            for fut in as_completed(futures):
                try:
                    rows = fut.result()
                    rows = rows if batched else [rows]
                except Exception as exc:  # the worker died: record it
                    rows = [
                        {
                            "run": i,
                            "seed": int(seeds[i]),
                            "status": "error",
                            "success": False,
                            "error": f"worker failure: {type(exc).__name__}: {exc}",
                            "overrides": "",
                        }
                        for i in runs_of[fut.key]
                    ]
                for row in rows:
                    write_row(store, row)
                stored += len(rows)
                if bar is not None:
                    bar.to(done_before + stored)
        except KeyboardInterrupt:
            # shutting the cluster down mid-task makes distributed log warnings and heartbeat
            # tracebacks (driver and workers): not for users, whose rows are safe on disk
            _silence_distributed()
            try:
                client.run(_silence_distributed)
                client.cancel(futures if "futures" in locals() else [])
            except Exception:  # noqa: BLE001 - best effort while shutting down
                pass
            raise
        finally:
            if bar is not None:
                bar.close(complete=done_before + stored >= spec.runs)
            client.close()
            if cluster is not None:
                cluster.close()
    return write_report(spec, out)

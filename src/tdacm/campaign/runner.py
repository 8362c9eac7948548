"""Running a campaign on Dask, streaming one Parquet row per run, resumable.

The store is a directory ``OUT/results/`` of one-row Parquet files ``run-000042.parquet``, all
with the fixed schema :data:`ROW_SCHEMA` (so the directory is one Parquet dataset:
``pandas.read_parquet(OUT / "results")`` reads it as one table; :func:`read_results` does the
same sorted by run and also reads stores of older versions).  Only the
driver writes, each row to a temporary name renamed atomically, so an interrupted campaign
holds complete rows only; on restart the runs already stored are skipped and the missing ones
run, so no run is lost or run twice.  A run that raises is stored with ``status = "error"`` and
its traceback; the campaign goes on.

Runs execute on a Dask cluster: a ``LocalCluster`` of ``workers`` processes by default, or the
scheduler at ``scheduler`` (``tcp://host:port``) with no code change.  Each run is a pure
function of ``(spec, index, seed)``, so the same spec gives the same rows on any cluster.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
import traceback
from pathlib import Path

import numpy as np

from .._extras import require
from .spec import CampaignSpec, CampaignSpecError, load_spec, sample_overrides, to_toml

#: Summary fields copied into the store (None -> NaN for numbers).
ROW_FIELDS = (
    "initial_rmse",
    "final_rmse",
    "min_rmse",
    "late_rmse_1s",
    "within_0.01_last_2s",
    "time_to_0.01",
    "time_to_0.001",
    "mode_switch_time",
    "terminated",
    "termination_reason",
    "wall_time_s",
    "max_tension",
    "max_thrust",
    "local_detection_rate",
    "estimation_source",
    "strain_estimation_rms",
    "drone_position_estimation_rms",
    "final_rmse_true",
    "final_camera_position_error_m",
    "final_camera_rotation_error_deg",
    "final_drone_position_error_m",
    "final_target_estimate_error_deg",
    "final_target_estimate_sigma_deg",
)


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
        _, summary = Simulation(scenario, duration=spec.duration, seed=int(seed)).run(None)
        for k in ROW_FIELDS:
            row[k] = summary.get(k)
        final = summary.get("final_rmse")
        row["success"] = bool(
            final is not None
            and np.isfinite(final)
            and final <= spec.success_rmse
            and not summary.get("terminated")
        )
    except Exception as exc:  # a failing run is data, not the end of the campaign
        row["status"] = "error"
        row["error"] = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=8)}"
        row["success"] = False
        row.setdefault("overrides", "")
    row["run_wall_s"] = time.perf_counter() - t0
    return row


def _silence_distributed() -> None:
    import logging

    for name in ("distributed", "distributed.nanny", "distributed.worker", "tornado"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _row_path(store: Path, index: int) -> Path:
    return store / f"run-{index:06d}.parquet"


_STRING_FIELDS = ("status", "termination_reason", "overrides", "error", "estimation_source")
_BOOL_FIELDS = ("success", "terminated")
_INT_FIELDS = ("run", "seed")
#: Column order of the store; every other column is float64 (None -> NaN).
COLUMNS = ("run", "seed", "status", "success", *ROW_FIELDS, "run_wall_s", "overrides", "error")


def row_schema():
    """The fixed Arrow schema of a stored row (the same for every run, whatever its
    outcome: a metric that is missing in one run is NaN/null, never a column of type null)."""
    pa = require("pyarrow", "campaign")

    def typ(k):
        if k in _INT_FIELDS:
            return pa.int64()
        if k in _BOOL_FIELDS:
            return pa.bool_()
        if k in _STRING_FIELDS:
            return pa.string()
        return pa.float64()

    return pa.schema([(k, typ(k)) for k in COLUMNS])


def _typed(k, v):
    if k in _INT_FIELDS:
        return int(v)
    if k in _BOOL_FIELDS:
        return None if v is None else bool(v)
    if k in _STRING_FIELDS:
        return "" if v is None else str(v)
    return float("nan") if v is None else float(v)


def write_row(store: Path, row: dict) -> None:
    pa = require("pyarrow", "campaign")
    pq = require("pyarrow.parquet", "campaign")

    schema = row_schema()
    table = pa.Table.from_pylist([{k: _typed(k, row.get(k)) for k in COLUMNS}], schema=schema)
    path = _row_path(store, row["run"])
    # hidden temporary name: pyarrow datasets skip files starting with "." (a partial row is
    # never read), and the rename is atomic: a row is either complete or absent
    tmp = path.with_name(f".{path.name}.tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def completed_runs(store: Path) -> set[int]:
    """Indices already in the store (complete rows only)."""
    return {int(p.stem.split("-")[1]) for p in store.glob("run-*.parquet")}


def read_results(out):
    """All stored rows of campaign folder ``out`` as one pandas DataFrame sorted by run index
    (columns :data:`COLUMNS`, see ``docs/campaigns.md``); an empty DataFrame if none.
    Equivalent to ``pandas.read_parquet(out / "results")`` plus the sort, and it also reads
    rows written with the schema of older versions (cast to :func:`row_schema`)."""
    pd = require("pandas", "campaign")
    pa = require("pyarrow", "campaign")
    pq = require("pyarrow.parquet", "campaign")

    store = Path(out) / "results"
    files = sorted(store.glob("run-*.parquet"))
    if not files:
        return pd.DataFrame(columns=list(COLUMNS))
    schema = row_schema()
    tables = []
    for f in files:
        t = pq.read_table(f)
        cols = {}
        for field in schema:
            if field.name in t.column_names:
                cols[field.name] = t[field.name].cast(field.type)
            else:
                cols[field.name] = pa.nulls(len(t), field.type)
        tables.append(pa.table(cols, schema=schema))
    return pa.concat_tables(tables).to_pandas().sort_values("run", ignore_index=True)


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
    from .report import write_report

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
    if todo:
        cluster = None
        if scheduler:
            client = Client(scheduler)
        else:
            n = workers or max(1, (os.cpu_count() or 1))
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
            from tqdm import tqdm

            from .._log import progress_enabled

            bar = tqdm(
                total=spec.runs,
                initial=done_before,
                desc=f"campaign {spec.scenario}",
                unit="run",
                disable=not progress_enabled(),
            )
        try:
            spec_dict = {k: v for k, v in spec.__dict__.items()}
            futures = [
                client.submit(
                    execute_run, spec_dict, i, int(seeds[i]), pure=False, key=f"run-{i}-{seeds[i]}"
                )
                for i in todo
            ]
            for fut in as_completed(futures):
                try:
                    row = fut.result()
                except Exception as exc:  # the worker died: record it
                    i = int(fut.key.split("-")[1])
                    row = {
                        "run": i,
                        "seed": int(seeds[i]),
                        "status": "error",
                        "success": False,
                        "error": f"worker failure: {type(exc).__name__}: {exc}",
                        "overrides": "",
                    }
                write_row(store, row)
                if bar is not None:
                    bar.update(1)
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
                bar.close()
            client.close()
            if cluster is not None:
                cluster.close()
    return write_report(spec, out)

"""The campaign store: one-row Parquet files ``OUT/results/run-000042.parquet`` with the
fixed schema :func:`row_schema`, written atomically by the driver and read back as one table.
"""

from __future__ import annotations

import os
from pathlib import Path

from .._extras import require

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
    "termination",
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
    # servoing into contact ([touch]; NaN for the other scenarios)
    "hold_duration",
    "landings",
    "hold_force_rms_rel",
    "hold_force_estimate_error_rms",
    "hold_image_error_max",
    "hold_image_error_true_max",
    "hold_image_error_servo_max",
    "hold_force_mean",
    "max_contact_force",
)


def _row_path(store: Path, index: int) -> Path:
    return store / f"run-{index:06d}.parquet"


_STRING_FIELDS = (
    "status",
    "termination_reason",
    "termination",
    "overrides",
    "error",
    "estimation_source",
)
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
    (columns :data:`COLUMNS`, see ``docs/campaigns.md``); an empty DataFrame if the campaign
    stored none yet. Equivalent to ``pandas.read_parquet(out / "results")`` plus the sort, and
    it also reads rows written with the schema of older versions (cast to
    :func:`row_schema`). A missing folder raises ``FileNotFoundError`` naming ``out`` (a typo
    is not an empty campaign)."""
    pd = require("pandas", "campaign")
    pa = require("pyarrow", "campaign")
    pq = require("pyarrow.parquet", "campaign")

    if not Path(out).is_dir():
        raise FileNotFoundError(f"out: campaign folder {out} does not exist or is not a folder")
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

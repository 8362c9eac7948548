"""Robustness campaigns: many seeded closed-loop runs on Dask, a resumable Parquet store and a
report (``tdacm campaign SPEC.toml``)."""

from .report import wilson_interval, write_report
from .runner import execute_run, run_campaign
from .spec import CampaignSpec, CampaignSpecError, load_spec, parse_spec, sample_overrides, to_toml
from .store import completed_runs, read_results

__all__ = [
    "CampaignSpec",
    "CampaignSpecError",
    "completed_runs",
    "execute_run",
    "load_spec",
    "parse_spec",
    "read_results",
    "run_campaign",
    "sample_overrides",
    "to_toml",
    "wilson_interval",
    "write_report",
]

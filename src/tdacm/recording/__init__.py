"""Recordings in the robotics ecosystem's format: a run folder exported as MCAP with standard
ROS 2 message types (:mod:`.export`, viewable in Foxglove, replayable with ``ros2 bag play``),
and MCAP recordings imported through a topic map into time-stamped signals (:mod:`.ingest`), and re-run offline through the closed loop's perception,
estimation and servo-feature blocks (:mod:`.replay`).
See docs/recordings.md."""

from ..live.msgdefs import schema_text
from .export import DEFAULT_SECTIONS, DEFAULT_TOPICS, ExportError, export_run, load_run_folder
from .ingest import (
    DEFAULT_TOPIC_MAP,
    RecordingError,
    Signal,
    check_mcap,
    load_signals,
    load_topic_map,
    pose_matrices,
    read_mcap,
    save_signals,
)
from .replay import ReplayResult, replay

__all__ = [
    "DEFAULT_SECTIONS",
    "DEFAULT_TOPICS",
    "DEFAULT_TOPIC_MAP",
    "ExportError",
    "RecordingError",
    "ReplayResult",
    "Signal",
    "check_mcap",
    "export_run",
    "load_run_folder",
    "load_signals",
    "load_topic_map",
    "pose_matrices",
    "read_mcap",
    "replay",
    "save_signals",
    "schema_text",
]

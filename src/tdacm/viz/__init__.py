"""Visual outputs: figures of a run (:mod:`.figures`), the captioned video (:mod:`.video`),
3-D replays (:mod:`.replay`) and the Rerun recording (:mod:`.rerun_log`)."""

from .figures import KINDS, plot_run, plot_run_dir
from .replay import replay_frames, replay_run, write_animation
from .rerun_log import record_run
from .video import compose_frame, write_video

__all__ = [
    "KINDS",
    "compose_frame",
    "plot_run",
    "plot_run_dir",
    "record_run",
    "replay_frames",
    "replay_run",
    "write_animation",
    "write_video",
]

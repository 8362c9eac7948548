"""Visual outputs: 3-D replays of runs."""

from .replay import replay_frames, replay_run, write_animation

__all__ = ["replay_frames", "replay_run", "write_animation"]

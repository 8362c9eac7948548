"""Watch a run live: the robot's state as ROS 2 messages, step by step (:mod:`.messages`, the
builders ``tdacm export`` writes to MCAP too), published as the run goes by a Foxglove
WebSocket server (:mod:`.server`, the ``live`` extra), with per-period observers of a run
(:mod:`.run`: publish, pace to the wall clock). See docs/live.md."""

from pathlib import Path

from .messages import DEFAULT_SECTIONS, DEFAULT_TOPICS, RobotMessages, arm_topics
from .msgdefs import schema_text
from .run import LiveRun, RealTime, chain, row_of_log, row_of_step
from .server import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    IMAGE_RATE_HZ,
    PROGRESS_TOPIC,
    PUBLISH_RATE_HZ,
    PUBLISH_SHARE,
    LiveError,
    LiveServer,
    is_loopback,
    parse_address,
)

#: The shipped Foxglove layout of these topics (docs/live.md).
LAYOUT = Path(__file__).with_name("foxglove-layout.json")

__all__ = [
    "LAYOUT",
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "DEFAULT_SECTIONS",
    "DEFAULT_TOPICS",
    "IMAGE_RATE_HZ",
    "PROGRESS_TOPIC",
    "PUBLISH_RATE_HZ",
    "PUBLISH_SHARE",
    "LiveError",
    "LiveRun",
    "LiveServer",
    "RealTime",
    "RobotMessages",
    "arm_topics",
    "chain",
    "is_loopback",
    "parse_address",
    "row_of_log",
    "row_of_step",
    "schema_text",
]

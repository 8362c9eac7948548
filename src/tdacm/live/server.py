"""A Foxglove WebSocket server publishing the robot's ROS 2 messages as a run goes.

:class:`LiveServer` starts the server of the PyPI package ``foxglove-sdk`` (the ``live``
extra) and advertises one channel per topic of :class:`~.messages.RobotMessages` (ROS 2
``.msg`` schemas, CDR messages: the topics, types and frames of ``tdacm export``), plus
``/tdacm/progress`` (JSON: simulated time, fraction done, speed against the wall clock).
:meth:`LiveServer.publish` sends one control step; it does nothing unless a client subscribes
(a server nobody watches costs one clock read per step), sends at most :data:`PUBLISH_RATE_HZ`
steps a second of wall clock and spends at most :data:`PUBLISH_SHARE` of the wall clock on it
(each published step whole; the steps between are skipped, not averaged), more when the run
has time to spare (a paced run: ``slack``), and re-renders the
camera images (:class:`~tdacm.vision.PlanarRenderer`, as ``tdacm export --images``) at most
:data:`IMAGE_RATE_HZ` times a second, only for a client subscribed to them. The topics sent
once (``/tf_static``, the targets, the goal camera pose) are sent again when a client
subscribes to them later.

The server reads the run and never writes to it: a run with a server gives the same results
as without, bit for bit.

Clients speak Foxglove's WebSocket protocol; ``foxglove-sdk`` 0.30 names its subprotocol
``foxglove.sdk.v1`` (the protocol of ``foxglove.websocket.v1`` under a new name): the Foxglove
app connects (Open connection, Foxglove WebSocket, ``ws://localhost:8765``), and Lichtblick
from the releases that offer ``foxglove.sdk.v1`` (its sources of 1.28 do).
"""

from __future__ import annotations

import ipaddress
import json
import logging
import math
import time

import numpy as np

from .._extras import require
from .messages import STATIC_TOPICS, RobotMessages, image_topic
from .msgdefs import schema_text

log = logging.getLogger(__name__)

#: The address the server listens on unless asked: this machine only.
DEFAULT_HOST = "127.0.0.1"
#: Foxglove's default port for a WebSocket connection.
DEFAULT_PORT = 8765
#: At most this many control steps a second of wall clock are published.
PUBLISH_RATE_HZ = 30.0
#: At most this share of the wall clock goes into publishing (building, encoding, rendering
#: the images): after a publish that took ``c`` seconds the next one waits ``c / share``, so a
#: client watching costs a run at most ``share / (1 - share)`` of its time (11 %), on a busy
#: machine by publishing less often.
PUBLISH_SHARE = 0.1
#: Camera images are rendered and published at most this many times a second.
IMAGE_RATE_HZ = 10.0
#: How long (s) :meth:`LiveServer.close` waits for the last messages to reach a subscribed
#: client before it stops the server.
LINGER_S = 0.25
#: The topic of the run's progress (JSON, :data:`PROGRESS_SCHEMA`).
PROGRESS_TOPIC = "/tdacm/progress"
#: The JSON Schema of a progress message.
PROGRESS_SCHEMA = {
    "title": "tdacm.Progress",
    "type": "object",
    "properties": {
        "scenario": {"type": "string", "description": "the run's scenario"},
        "t": {"type": "number", "description": "simulated time (s)"},
        "duration": {"type": "number", "description": "the run's duration (s)"},
        "fraction": {"type": "number", "description": "t / duration"},
        "step": {"type": "integer", "description": "control steps done"},
        "wall_time": {"type": "number", "description": "wall-clock time since the start (s)"},
        "speed": {"type": "number", "description": "simulated seconds per wall-clock second"},
        "state": {"type": "string", "description": "running, done, ended early or interrupted"},
        "reason": {"type": ["string", "null"], "description": "why the run ended early"},
    },
}


class LiveError(ValueError):
    """An address that cannot be served (malformed, or the port in use); the message says
    which."""


def parse_address(text: str) -> tuple[str, int]:
    """``(host, port)`` of ``[HOST:]PORT`` (``PORT`` alone: :data:`DEFAULT_HOST`; an IPv6
    host in brackets, ``[::1]:8765``; port 0: a free port chosen by the system)."""
    text = str(text).strip()
    host, sep, port = text.rpartition(":")
    if not sep:
        host = DEFAULT_HOST
    elif host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise LiveError(f"must be [HOST:]PORT with a port from 0 to 65535, got {text!r}")
    if not host:
        raise LiveError(f"must be [HOST:]PORT, got {text!r} (no host before ':')")
    return host, int(port)


def is_loopback(host: str) -> bool:
    """True if ``host`` names this machine only (``localhost``, 127.0.0.0/8, ``::1``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class _Listener:
    """The server's callbacks (called from its own thread): which static topics a client
    subscribed to since they were last sent."""

    def __init__(self):
        self.pending: set[str] = set()
        self.subscriptions = 0

    def on_subscribe(self, client, channel) -> None:
        self.subscriptions += 1
        if channel.topic in STATIC_TOPICS:
            self.pending.add(channel.topic)

    def on_unsubscribe(self, client, channel) -> None:
        pass


class LiveServer:
    """A Foxglove WebSocket server on ``host:port`` (module docstring); port 0 picks a free
    port (:attr:`port`). Raises :class:`LiveError` if the port is in use, and
    :class:`~tdacm._extras.MissingExtraError` without the ``live`` extra.

    ``rate_hz`` and ``image_rate_hz``: the most steps and camera images a second of wall
    clock that :meth:`publish` sends; ``share``: the most of the wall clock it spends
    (:data:`PUBLISH_SHARE`). Use as a context manager, or call :meth:`close`.

    For a loop of one's own (docs/live.md)::

        with LiveServer(port=8765) as server:
            server.attach(RobotMessages.of_world(world))
            for ...:
                server.publish(t, {"q": q, "u": u, ...})
    """

    def __init__(
        self,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        *,
        name: str = "tdacm",
        rate_hz: float = PUBLISH_RATE_HZ,
        image_rate_hz: float = IMAGE_RATE_HZ,
        share: float = PUBLISH_SHARE,
    ):
        foxglove = require("foxglove", "live")
        self._serialize = require("mcap_ros2._dynamic", "live").serialize_dynamic
        from foxglove.websocket import Capability

        for what, v in (("rate_hz", rate_hz), ("image_rate_hz", image_rate_hz)):
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{what} must be a finite positive number, got {v!r}")
        if not (isinstance(share, int | float) and 0 < share <= 1):
            raise ValueError(f"share must be in (0, 1], got {share!r}")
        self.host = str(host)
        self._foxglove = foxglove
        self._context = foxglove.Context()
        self._listener = _Listener()
        try:
            self._server = foxglove.start_server(
                name=name,
                host=self.host,
                port=int(port),
                context=self._context,
                capabilities=[Capability.Time],
                server_listener=self._listener,
            )
        except RuntimeError as exc:
            reason = str(exc).removeprefix("FoxgloveError: ")
            if "in use" in reason:
                reason = "the port is in use (pick another one, or 0 for any free port)"
            raise LiveError(f"cannot listen on {self.host}:{port}: {reason}") from None
        #: the port the server listens on
        self.port = int(self._server.port)
        self.rate_hz, self.image_rate_hz = float(rate_hz), float(image_rate_hz)
        self.share = float(share)
        self.messages: RobotMessages | None = None
        self._channels: dict = {}
        self._encoders: dict = {}
        self._progress = None
        self._next_rate = -math.inf  # when the rate lets the next step out (perf_counter)
        self._next_share = -math.inf  # when the share does
        #: how long the last publish took (s)
        self.last_cost = 0.0
        self._last_image = -math.inf
        self._renderers: dict = {}
        self._static_ns = 0
        #: steps published (sent to at least one client)
        self.published = 0

    # ------------------------------------------------------------------ set-up
    @property
    def url(self) -> str:
        """``ws://host:port``, what a Foxglove client opens."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    @property
    def subscriptions(self) -> int:
        """How many subscriptions clients made so far (all topics, all clients)."""
        return self._listener.subscriptions

    def attach(self, messages: RobotMessages, start_ns: int = 0) -> None:
        """Advertise the channels of a robot's messages (``messages``, one channel per topic)
        and of the progress, and send the static topics stamped ``start_ns``."""
        foxglove = self._foxglove
        self.messages = messages
        for topic, kind in messages.topics.items():
            if topic in self._channels:
                continue
            if kind not in self._encoders:
                self._encoders[kind] = self._serialize(kind, schema_text(kind))[kind]
            schema = foxglove.Schema(
                name=kind, encoding="ros2msg", data=schema_text(kind).encode("utf-8")
            )
            self._channels[topic] = foxglove.Channel(
                topic, schema=schema, message_encoding="cdr", context=self._context
            )
        if self._progress is None:
            self._progress = foxglove.Channel(
                PROGRESS_TOPIC, schema=PROGRESS_SCHEMA, context=self._context
            )
        self._static_ns = int(start_ns)
        self._send(messages.static(self._static_ns, self.subscribed()), self._static_ns)

    def subscribed(self) -> set[str]:
        """The topics at least one client subscribes to."""
        return {t for t, ch in self._channels.items() if ch.has_sinks()}

    # ------------------------------------------------------------------ publishing
    def _send(self, msgs, ns: int) -> None:
        kinds = self.messages.topics
        for topic, msg in msgs:
            data = self._encoders[kinds[topic]](msg)
            self._channels[topic].log(bytes(data), log_time=int(ns))

    def due(self, now: float | None = None, slack: float | None = None) -> bool:
        """True if a step published now would be sent: the rate allows it, and the share does
        or the run has ``slack`` seconds to spare (a paced run's time until its next period is
        due, :meth:`tdacm.live.RealTime.slack`) that the last publish's cost fits in."""
        now = time.perf_counter() if now is None else now
        if now < self._next_rate:
            return False
        return now >= self._next_share or (slack is not None and slack >= self.last_cost)

    def publish(
        self, t: float, row: dict, *, final: bool = False, slack: float | None = None
    ) -> bool:
        """Send the control step at simulated time ``t`` (s) whose logged values are ``row``
        (:data:`~.messages.ROW_SERIES`: ``q`` and what else the run has) to the subscribed
        clients when :meth:`due` (``slack``: the time the run has to spare, s); ``final``: the
        last step, sent whatever the rate and share. Returns True if it was sent."""
        now = time.perf_counter()
        if self.messages is None or not (final or self.due(now, slack)):
            return False
        self._next_rate = now + 1.0 / self.rate_hz
        topics = self.subscribed()
        if not topics:
            return False
        ns = int(round(float(t) * 1e9)) + self._static_ns
        pending = self._listener.pending
        if pending:  # a client subscribed to a static topic after it was sent
            again = {p for p in list(pending) if p in topics}
            pending.difference_update(again)
            self._send(self.messages.static(self._static_ns, again), self._static_ns)
        self._send(self.messages.step(ns, row, topics), ns)
        cams = [c for c in self.messages.cameras if image_topic(c) in topics]
        if cams and (final or now - self._last_image >= 1.0 / self.image_rate_hz):
            self._last_image = now
            q = np.asarray(row["q"], float)
            for cam in cams:
                self._send([self.messages.image(cam, ns, self._render(cam, q))], ns)
        self._server.broadcast_time(ns)
        self.published += 1
        cost = self.last_cost = time.perf_counter() - now
        self._next_share = now + cost / self.share
        return True

    def _render(self, cam: str, q) -> np.ndarray:
        """Camera ``cam``'s image at ``q`` (RGB, the planar renderer)."""
        camera, g, scene = self.messages.camera_view(cam, q)
        renderer = self._renderers.get(cam)
        if renderer is None:
            from ..vision import PlanarRenderer

            renderer = self._renderers[cam] = PlanarRenderer(scene)
        return np.ascontiguousarray(renderer.render(camera, g)[:, :, :3])

    def progress(self, **fields) -> None:
        """Send a progress message (:data:`PROGRESS_SCHEMA`'s fields) if a client listens."""
        if self._progress is not None and self._progress.has_sinks():
            self._progress.log(json.dumps(fields).encode("utf-8"))

    # ------------------------------------------------------------------ end
    def close(self) -> None:
        """Stop the server (its clients are disconnected; a client still subscribed gets
        :data:`LINGER_S` to receive the last messages first) and the renderers."""
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()
        if self._server is not None:
            watched = self.subscribed() or (
                self._progress is not None and self._progress.has_sinks()
            )
            if watched:  # the server sends from its own thread: let it send the last messages
                time.sleep(LINGER_S)
            self._server.stop()
            self._server = None

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

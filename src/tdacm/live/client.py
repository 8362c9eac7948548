"""A small client of Foxglove's WebSocket protocol, to check a live server without the app
(the tests, benchmarks/bench_live.py, a headless machine): the published spec of
``foxglove.websocket.v1`` (named ``foxglove.sdk.v1`` by foxglove-sdk 0.30; the client offers
both names): the server's JSON ``serverInfo`` and ``advertise`` messages, the client's
``subscribe``, the binary message data (opcode 1: subscription id u32, log time u64, payload;
little-endian). Over the PyPI package ``websockets`` (the ``live`` extra). Decode a payload with
the ROS 2 definitions of its channel's schema (e.g. ``rosbags``' ``deserialize_cdr``)."""

from __future__ import annotations

import json
import socket
import struct
import time
from contextlib import ExitStack

from .._extras import require

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def free_port() -> int:
    """A port free on the loopback interface now (the system's choice)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class FoxgloveClient:
    """Connects to ``ws://host:port`` (retrying until ``timeout`` s while the server starts),
    keeps the advertised channels and collects the messages of its subscriptions:
    ``messages[topic] = [(log_time, payload, receive wall time), ...]``."""

    def __init__(self, port: int, host: str = "127.0.0.1", timeout: float = 120.0):
        connect = require("websockets.sync.client", "live").connect
        self._closed_error = require("websockets.exceptions", "live").ConnectionClosed
        deadline = time.monotonic() + timeout
        while True:
            try:
                self._stack = ExitStack()
                self.ws = self._stack.enter_context(connect(
                    f"ws://{host}:{port}", subprotocols=SUBPROTOCOLS, proxy=None,
                    open_timeout=5, max_size=None))  # fmt: skip
                break
            except (OSError, TimeoutError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        self.server_info = None
        self.channels: dict[str, dict] = {}  # topic -> advertised channel
        self.subscriptions: dict[int, str] = {}  # subscription id -> topic
        self.messages: dict[str, list] = {}
        self.closed = False

    def poll(self, timeout: float = 0.1) -> bool:
        """Handle one message from the server; False on a time-out or a closed connection."""
        try:
            m = self.ws.recv(timeout=timeout)
        except TimeoutError:
            return False
        except self._closed_error:
            self.closed = True
            return False
        if isinstance(m, str):
            op = json.loads(m)
            if op["op"] == "serverInfo":
                self.server_info = op
            elif op["op"] == "advertise":
                for ch in op["channels"]:
                    self.channels[ch["topic"]] = ch
        elif m[0] == 1:  # message data
            sub, log_time = struct.unpack_from("<IQ", m, 1)
            topic = self.subscriptions[sub]
            self.messages.setdefault(topic, []).append((log_time, bytes(m[13:]), time.time()))
        return True

    def wait_for(self, cond, timeout: float) -> bool:
        """Poll until ``cond()`` or ``timeout`` s or the connection closes."""
        deadline = time.monotonic() + timeout
        while not cond():
            if self.closed or time.monotonic() > deadline:
                return False
            self.poll()
        return True

    def subscribe(self, topics) -> None:
        subs = []
        for topic in topics:
            sid = len(self.subscriptions) + 1
            self.subscriptions[sid] = topic
            subs.append({"id": sid, "channelId": self.channels[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def close(self) -> None:
        self._stack.close()
        self.closed = True

"""Import an MCAP recording (ROS 2 messages) into time-stamped numpy signals.

A *topic map* says which of the recording's topics become which tdacm signal: a dict (or a TOML
file with a ``[topics]`` table) ``topic -> signal``, where the signal is

* a name: the message's values as one signal (for ``sensor_msgs/JointState``: the first
  non-empty field among ``position``, ``velocity``, ``effort``);
* for ``sensor_msgs/JointState``, a table ``{position = "strains", velocity = "strain_rates",
  effort = "..."}``: one signal per field;
* for ``tf2_msgs/TFMessage`` (``/tf``, ``/tf_static``), a table ``{child_frame = "signal"}``:
  the transform from the frame's parent to the frame, as a pose.

For example (a lab's names)::

    [topics]
    "/vicon/drone/pose" = "drone_pose"
    "/tendons/tension" = { effort = "tensions" }
    "/arm/joints" = { position = "strains", velocity = "strain_rates" }
    "/tf" = { tip = "tip_tf" }

Values per message type (``names`` label the last axis):

==================================================  =======================================
``geometry_msgs/PoseStamped``, ``PoseWithCovariance  (T, 7) ``x, y, z, qx, qy, qz, qw``
Stamped``, ``TransformStamped``, ``nav_msgs/Odometry``
(its pose), a ``TFMessage`` frame
``geometry_msgs/PointStamped``, ``Vector3Stamped``   (T, 3) ``x, y, z``
``sensor_msgs/JointState``                           (T, n) the joint names
``std_msgs/Float64MultiArray`` (``Float32...``)      (T, n) the dimension label split at commas
                                                     (else ``signal[i]``); several dimensions:
                                                     (T, n_1, ..., n_d), the last label's names
``std_msgs/Float64``, ``Float32``                    (T,)
``sensor_msgs/CameraInfo``                           (T, 6) ``fx, fy, cx, cy, width, height``
``sensor_msgs/Image`` (8-bit encodings)              (T, H, W[, C]) uint8
==================================================  =======================================

Times: the header stamp when the message has one, else the MCAP log time (seconds, absolute;
``t0`` is subtracted if given). A tdacm export imports with :data:`DEFAULT_TOPIC_MAP`.
"""

from __future__ import annotations

import logging
import struct
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._extras import require

log = logging.getLogger(__name__)

POSE_NAMES = ("x", "y", "z", "qx", "qy", "qz", "qw")

#: The topic map of a tdacm export (:data:`tdacm.recording.export.DEFAULT_TOPICS`).
DEFAULT_TOPIC_MAP = {
    "/tdacm/drone/pose": "drone_pose",
    "/tdacm/tip/pose": "tip_pose",
    "/tdacm/target/pose": "target_pose",
    "/tdacm/goal/camera_pose": "goal_camera_pose",
    "/tdacm/strains": {
        "position": "strains",
        "velocity": "strain_rates",
        "effort": "strain_forces",
    },
    "/tdacm/tendons": {"effort": "tensions", "position": "tendon_lengths"},
    "/tdacm/rotors": {"effort": "thrusts"},
    "/tdacm/servo/features": "features",
    "/tdacm/servo/feature_error": "feature_error",
    "/tdacm/servo/points_local": "points_local",
    "/tdacm/servo/rmse": "rmse",
    "/tdacm/C_L/camera_info": "C_L_info",
    "/tdacm/C_G/camera_info": "C_G_info",
    "/tdacm/C_L/image_raw": "C_L_image",
    "/tdacm/C_G/image_raw": "C_G_image",
}

_JOINT_FIELDS = ("position", "velocity", "effort")


class RecordingError(ValueError):
    """A recording or a topic map that cannot be imported; the message names it."""


@dataclass(frozen=True)
class Signal:
    """One imported signal: ``values[k]`` at time ``t[k]`` (s); ``names`` label the last
    axis of ``values``; ``topic`` and ``msg_type`` say where it came from."""

    name: str
    t: np.ndarray
    values: np.ndarray
    names: tuple
    topic: str
    msg_type: str

    def __post_init__(self):
        for key in ("t", "values"):
            a = np.asarray(getattr(self, key)).copy()
            a.setflags(write=False)
            object.__setattr__(self, key, a)

    def __len__(self) -> int:
        return len(self.t)


def load_topic_map(source) -> dict:
    """A topic map from a dict, or a TOML file whose ``[topics]`` table (or top level) maps
    topics to signals; checked (a name per topic, no signal twice; without ``[topics]``, a
    table whose name is not a topic, ``/...``, is refused as a misnamed section)."""
    if isinstance(source, dict):
        raw = source
    else:
        p = Path(source)
        if not p.is_file():
            raise RecordingError(f"topic map {p} not found")
        try:
            raw = tomllib.loads(p.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise RecordingError(f"topic map {p}: {exc}") from None
        if "topics" not in raw:  # the map at the top level: a table there is a misnamed section
            for key, value in raw.items():
                if isinstance(value, dict) and not key.startswith("/"):
                    raise RecordingError(
                        f"topic map {p} has no [topics] table ([{key}] is not a topic: "
                        "write the map under [topics])"
                    )
        raw = raw.get("topics", raw)
    seen = set()
    out = {}
    for topic, target in raw.items():
        if isinstance(target, str):
            targets = [target]
        elif isinstance(target, dict) and all(isinstance(v, str) for v in target.values()):
            targets = list(target.values())
        else:
            raise RecordingError(
                f"topic map: {topic!r} must map to a signal name or a table of names, "
                f"got {target!r}"
            )
        for name in targets:
            if not name.isidentifier():
                raise RecordingError(f"topic map: signal name {name!r} (of {topic!r}) is not a "
                                     "valid identifier")  # fmt: skip
            if name in seen:
                raise RecordingError(f"topic map: signal {name!r} is given twice")
            seen.add(name)
        out[topic] = dict(target) if isinstance(target, dict) else target
    if not out:
        raise RecordingError("topic map is empty")
    return out


# ------------------------------------------------------------------ value extraction
def _pose7(p, o) -> list[float]:
    return [p.x, p.y, p.z, o.x, o.y, o.z, o.w]


def _values(kind: str, msg, name: str):
    """``(values, names)`` of one message (the table of the module docstring)."""
    if kind in ("geometry_msgs/msg/PoseStamped",):
        return _pose7(msg.pose.position, msg.pose.orientation), POSE_NAMES
    if kind in ("geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry"):
        return _pose7(msg.pose.pose.position, msg.pose.pose.orientation), POSE_NAMES
    if kind == "geometry_msgs/msg/TransformStamped":
        tr = msg.transform
        return _pose7(tr.translation, tr.rotation), POSE_NAMES
    if kind in ("geometry_msgs/msg/PointStamped", "geometry_msgs/msg/Vector3Stamped"):
        v = msg.point if kind.endswith("PointStamped") else msg.vector
        return [v.x, v.y, v.z], ("x", "y", "z")
    if kind in ("std_msgs/msg/Float64", "std_msgs/msg/Float32"):
        return float(msg.data), ()
    if kind in ("std_msgs/msg/Float64MultiArray", "std_msgs/msg/Float32MultiArray"):
        data = np.asarray(msg.data, float)
        dims = msg.layout.dim
        sizes = [int(d.size) for d in dims]
        if len(dims) > 1 and int(np.prod(sizes)) == data.size:
            data = data.reshape(sizes)  # row-major, the layout's strides
        width = data.shape[-1] if data.ndim else 0
        labels = dims[-1].label.split(",") if dims else []
        if len(labels) != width:
            labels = [f"{name}[{i}]" for i in range(width)]
        return data, tuple(labels)
    if kind == "sensor_msgs/msg/CameraInfo":
        k = msg.k
        return [k[0], k[4], k[2], k[5], msg.width, msg.height], (
            "fx", "fy", "cx", "cy", "width", "height",
        )  # fmt: skip
    if kind == "sensor_msgs/msg/Image":
        ch = {"mono8": 1, "8UC1": 1, "rgb8": 3, "bgr8": 3, "8UC3": 3, "rgba8": 4, "bgra8": 4}
        c = ch.get(msg.encoding)
        if c is None:
            raise RecordingError(f"{name}: image encoding {msg.encoding!r} is not 8-bit")
        a = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)
        a = a[:, : msg.width * c].reshape(msg.height, msg.width, c)
        return (a[:, :, 0] if c == 1 else a), (msg.encoding,)
    raise RecordingError(f"{name}: message type {kind} is not supported")


def _seconds(ns: np.ndarray) -> np.ndarray:
    """Seconds of integer nanoseconds (whole seconds plus the correctly rounded fraction)."""
    ns = np.asarray(ns, np.int64)
    return (ns // 1_000_000_000).astype(float) + (ns % 1_000_000_000) / 1e9


def _stamp_ns(msg, log_time: int) -> int:
    h = getattr(msg, "header", None)
    if h is None:
        return int(log_time)
    return int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)


class _Acc:
    """Values of one signal as messages arrive."""

    def __init__(self, name, topic, kind):
        self.name, self.topic, self.kind = name, topic, kind
        self.ns, self.values, self.names = [], [], None

    def add(self, ns, values, names):
        if self.names is None:
            self.names = tuple(names)
        elif tuple(names) != self.names:
            raise RecordingError(f"{self.topic}: the names of {self.name!r} change during the "
                                 f"recording ({self.names} then {tuple(names)})")  # fmt: skip
        self.ns.append(ns)
        self.values.append(values)

    def signal(self, t0_ns: int) -> Signal:
        ns = np.asarray(self.ns, np.int64)
        order = np.argsort(ns, kind="stable")
        dtype = np.uint8 if self.kind == "sensor_msgs/msg/Image" else float
        try:
            vals = np.asarray(self.values, dtype=dtype)[order]
        except ValueError:
            raise RecordingError(f"{self.topic}: the messages of {self.name!r} do not all have "
                                 "the same size") from None  # fmt: skip
        # the origin is removed in integer nanoseconds: epoch stamps (1.7e9 s) as floats
        # would keep only 0.2 us; a tdacm export's stamps come back to the nanosecond
        t = _seconds(ns[order] - t0_ns)
        return Signal(self.name, t, vals, self.names or (), self.topic, self.kind)


#: The first bytes of every MCAP file (the format's magic: 0x89, "MCAP", the major version 0,
#: CR, LF).
MCAP_MAGIC = b"\x89MCAP0\r\n"


def check_mcap(path) -> None:
    """Raise :class:`RecordingError` naming ``path`` unless the file starts as an MCAP file
    does (:data:`MCAP_MAGIC`): a text file, an image or a ZIP is refused in one line before the
    MCAP reader meets its bytes."""
    with open(path, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        what = "it is empty" if not head else "it does not start with the MCAP magic bytes"
        raise RecordingError(f"FILE {path} is not an MCAP recording ({what})")


def read_mcap(path, topic_map=None, *, t0: float | str | None = None) -> dict[str, Signal]:
    """Signals of the MCAP file ``path`` through ``topic_map`` (dict or TOML path; default
    :data:`DEFAULT_TOPIC_MAP`, the topics of a tdacm export that the file has). ``t0``: seconds
    subtracted from every time, in integer nanoseconds (``"first"``: the earliest time of the
    imported signals).

    Every message of a mapped topic is decoded with ``mcap_ros2.decoder.DecoderFactory`` from
    the schema embedded in the file."""
    exceptions = require("mcap.exceptions", "recording")
    DecoderNotFoundError, McapError = exceptions.DecoderNotFoundError, exceptions.McapError
    make_reader = require("mcap.reader", "recording").make_reader
    DecoderFactory = require("mcap_ros2.decoder", "recording").DecoderFactory

    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"FILE {path} not found")
    check_mcap(path)
    if not (t0 is None or t0 == "first" or isinstance(t0, int | float)):
        raise RecordingError(f"t0 must be seconds, 'first' or None, got {t0!r}")
    explicit = topic_map is not None
    tmap = load_topic_map(topic_map if explicit else DEFAULT_TOPIC_MAP)
    accs: dict[tuple, _Acc] = {}
    try:
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
            channels = summary.channels.values() if summary is not None else ()
            present = {c.topic for c in channels}
            if summary is not None and explicit:
                missing = [tp for tp in tmap if tp not in present]
                if missing:
                    raise RecordingError(f"topic map: {missing[0]!r} is not in {path} (topics: "
                                         f"{', '.join(sorted(present))})")  # fmt: skip
            wanted = [tp for tp in tmap if summary is None or tp in present]
            if not wanted:
                raise RecordingError(f"FILE {path} has none of the mapped topics")
            for schema, channel, message, msg in reader.iter_decoded_messages(topics=wanted):
                target = tmap[channel.topic]
                kind = schema.name
                _collect(accs, target, channel.topic, kind, msg, message.log_time)
    except DecoderNotFoundError as exc:
        raise RecordingError(f"FILE {path}: a mapped topic is not ROS 2 (ros2msg schema, CDR "
                             f"messages): {exc}") from None  # fmt: skip
    except (McapError, struct.error, EOFError, UnicodeDecodeError) as exc:
        # a damaged MCAP: the reader's own error, or a record cut short inside its parser
        raise RecordingError(f"FILE {path}: not a readable MCAP file ({exc})") from None
    signals = {}
    if t0 == "first":
        t0_ns = min((min(a.ns) for a in accs.values() if a.ns), default=0)
    else:
        t0_ns = round(float(t0 or 0.0) * 1e9)
    for acc in accs.values():
        signals[acc.name] = acc.signal(t0_ns)
    log.info("imported %d signals from %s", len(signals), path)
    return signals


def _collect(accs, target, topic, kind, msg, log_time):
    if kind == "tf2_msgs/msg/TFMessage":
        if not isinstance(target, dict):
            raise RecordingError(f"topic map: {topic!r} (tf2_msgs/TFMessage) must map child "
                                 "frames to signals, e.g. { tip = \"tip_tf\" }")  # fmt: skip
        for tr in msg.transforms:
            name = target.get(tr.child_frame_id)
            if name is not None:
                acc = accs.setdefault((topic, name), _Acc(name, topic, kind))
                v, n = _values("geometry_msgs/msg/TransformStamped", tr, name)
                acc.add(_stamp_ns(tr, log_time), v, n)
        return
    ns = _stamp_ns(msg, log_time)
    if kind == "sensor_msgs/msg/JointState":
        fields = (
            target
            if isinstance(target, dict)
            else {next((f for f in _JOINT_FIELDS if len(getattr(msg, f))), "position"): target}
        )
        for field, name in fields.items():
            if field not in _JOINT_FIELDS:
                raise RecordingError(f"topic map: {topic!r}: {field!r} is not a JointState "
                                     "field (position, velocity, effort)")  # fmt: skip
            acc = accs.setdefault((topic, name), _Acc(name, topic, kind))
            acc.add(ns, list(getattr(msg, field)), msg.name)
        return
    if isinstance(target, dict):
        raise RecordingError(f"topic map: {topic!r} ({kind}) must map to one signal name")
    acc = accs.setdefault((topic, target), _Acc(target, topic, kind))
    v, n = _values(kind, msg, target)
    acc.add(ns, v, n)


# ------------------------------------------------------------------ files and helpers
def save_signals(signals: dict[str, Signal], out) -> list[Path]:
    """One ``NAME.npz`` per signal in folder ``out`` (``t``, ``values``, ``names``, ``topic``,
    ``msg_type``); returns the paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, s in signals.items():
        p = out / f"{name}.npz"
        np.savez_compressed(p, t=s.t, values=s.values, names=np.asarray(s.names, dtype=str),
                            topic=s.topic, msg_type=s.msg_type)  # fmt: skip
        paths.append(p)
    return paths


def load_signals(folder) -> dict[str, Signal]:
    """The signals :func:`save_signals` wrote to ``folder``."""
    out = {}
    for p in sorted(Path(folder).glob("*.npz")):
        with np.load(p) as d:
            out[p.stem] = Signal(p.stem, d["t"], d["values"], tuple(d["names"].tolist()),
                                 str(d["topic"]), str(d["msg_type"]))  # fmt: skip
    return out


def pose_matrices(signal: Signal) -> np.ndarray:
    """(T, 4, 4) poses of a pose signal (values ``x, y, z, qx, qy, qz, qw``)."""
    from scipy.spatial.transform import Rotation

    v = np.asarray(signal.values, float)
    if v.ndim != 2 or v.shape[1] != 7:
        raise RecordingError(f"{signal.name} is not a pose signal (values {v.shape})")
    g = np.tile(np.eye(4), (len(v), 1, 1))
    if len(v):
        g[:, :3, :3] = Rotation.from_quat(v[:, 3:]).as_matrix()
    g[:, :3, 3] = v[:, :3]
    return g

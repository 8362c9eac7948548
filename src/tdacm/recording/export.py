"""Export a ``tdacm run`` folder as an MCAP recording in standard ROS 2 message types.

The file is written with the PyPI libraries ``mcap`` and ``mcap-ros2-support`` (no ROS
installation): every schema is the ROS 2 ``.msg`` text (:mod:`tdacm.live.msgdefs`, encoding
``ros2msg``) and every message is CDR, so Foxglove opens the file and ``ros2 bag play`` replays
it. Header stamps and log times are the run's ``t`` (nanoseconds, plus ``start_ns``).

The topics, message types and frames are those of :mod:`tdacm.live.messages` (the table is in
its docstring and in docs/recordings.md): the messages are built there, step by step, for this
file and for the live server (:mod:`tdacm.live`), so one Foxglove layout serves both. A run
folder holds no raw camera images (``video.mp4`` is the captioned composite), so images are
exported when given (``images=``) or re-rendered from the stored ``q`` by the planar renderer
(``render_every=``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._extras import require
from ..live.messages import (  # noqa: F401  (re-exported: the export's topics and frames)
    ARRAY_SERIES,
    BASE,
    C_G_FRAME,
    C_L_FRAME,
    DEFAULT_SECTIONS,
    DEFAULT_TOPICS,
    ROD_BASE,
    ROW_SERIES,
    TARGET_FRAME,
    TF,
    TIP,
    WORLD,
    FrameError,
    RobotMessages,
    arm_topics,
    camera_frame,
    cameras,
    checked_frame,
    image_topic,
    robot_arms,
    series_names,
    target_frame,
)
from ..live.msgdefs import schema_text

log = logging.getLogger(__name__)

#: QoS that ``ros2 bag play`` offers for ``/tf_static``: reliable, transient local (latched),
#: keep last 1, as ``ros2 bag record`` stores it in the channel metadata.
_LATCHED_QOS = (
    "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n"
    "  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n"
    "  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n"
    "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n"
    "  avoid_ros_namespace_conventions: false\n"
)


class ExportError(ValueError):
    """A run folder or an option that cannot be exported; the message names it."""


@dataclass(frozen=True)
class RunFolder:
    """What the export reads from a ``tdacm run`` folder: the stored series, the summary, the
    resolved scenario and its robot (:func:`tdacm.sim.build_world`)."""

    arrays: dict
    summary: dict
    scenario: object
    robot: object
    scene: object
    q_star: np.ndarray
    scenes: tuple = ()  # several arms: each arm's scene (its target); scene is arm 0's


def load_run_folder(run_dir) -> RunFolder:
    """Read ``run_dir`` (:func:`tdacm.sim.outputs.load_run`) and build its robot."""
    from ..sim import ScenarioError
    from ..sim.assemble import build_world
    from ..sim.outputs import RunDirError, load_run

    try:
        arrays, summary, sc = load_run(run_dir)
        world = build_world(sc)
    except (RunDirError, ScenarioError) as exc:
        raise ExportError(str(exc)) from None
    return RunFolder(arrays, summary, sc, world.robot, world.scene, world.q_star, world.scenes)


def messages_of(run: RunFolder, n_sections: int = DEFAULT_SECTIONS) -> RobotMessages:
    """The message builders of a run folder's robot, its series named as in its
    ``timeseries.csv``."""
    arms = robot_arms(run.robot, run.scene, run.scenes)
    names = series_names(run.arrays, run.robot.system.floating)
    return RobotMessages(run.robot, arms, run.q_star, names, n_sections)


def step_row(arrays: dict, k: int) -> dict:
    """Step ``k``'s row of a run's series (:data:`~tdacm.live.messages.ROW_SERIES`)."""
    return {key: arrays[key][k] for key in ROW_SERIES if key in arrays}


def export_run(
    run_dir,
    path,
    *,
    topics=None,
    n_sections: int = DEFAULT_SECTIONS,
    images: dict | None = None,
    render_every: int | None = None,
    start_ns: int = 0,
) -> Path:
    """Write the run folder ``run_dir`` as the MCAP file ``path``; returns the path.

    ``topics``: the topics to write (a subset of :data:`DEFAULT_TOPICS`; default all that the
    run has). ``n_sections``: rod intervals of ``/tf`` (frames at ``s_k = k L / n``, the last
    one the tip). ``images``: ``{"C_L" or "C_G": (t (K,), frames (K, H, W[, C]) uint8)}``;
    ``render_every``: re-render both cameras from the stored ``q`` every that many steps with
    :class:`~tdacm.vision.PlanarRenderer` (ignored for a camera given in ``images``).
    ``start_ns``: added to every stamp (0: stamps are the simulated time from the epoch)."""
    Writer = require("mcap_ros2.writer", "recording").Writer

    run = load_run_folder(run_dir)
    n_arms = len(robot_arms(run.robot, run.scene, run.scenes))
    known = {**DEFAULT_TOPICS, **arm_topics(n_arms)}
    topics = set(known if topics is None else topics)
    unknown = sorted(topics - set(known))
    if unknown:
        raise ExportError(f"topics: unknown {unknown[0]!r} (known: {', '.join(known)})")
    if int(n_sections) < 1:
        raise ExportError(f"n_sections must be a positive integer, got {n_sections!r}")
    if render_every is not None and int(render_every) < 1:
        raise ExportError(f"render_every must be a positive integer, got {render_every!r}")
    images = dict(images or {})
    cams = cameras(n_arms)
    bad = sorted(set(images) - set(cams))
    if bad:
        raise ExportError(f"images: unknown camera {bad[0]!r} ({', '.join(cams)})")
    for cam, given in images.items():
        ti, fr = (np.asarray(x) for x in given)
        if ti.ndim != 1 or len(fr) != len(ti) or np.any(np.diff(ti) < 0):
            raise ExportError(f"images[{cam!r}]: give (t, frames) with increasing t, one per "
                              f"frame (got {ti.shape} times, {len(fr)} frames)")  # fmt: skip
        for f in fr:  # before the file is opened: no half-written recording
            try:
                checked_frame(f)
            except FrameError as exc:
                raise ExportError(str(exc)) from None
    a = run.arrays
    t = np.asarray(a["t"], float)
    stamps = np.rint(t * 1e9).astype(np.int64) + int(start_ns)
    msgs = messages_of(run, int(n_sections))
    if render_every is not None:
        for cam in cams:
            if cam not in images and image_topic(cam) in topics:
                images[cam] = render_images(run, cam, int(render_every))
    arrays = dict(a)
    for key in ("q", "qd", "tau", "u"):
        if key in arrays:
            arrays[key] = np.asarray(arrays[key], float).reshape(len(t), -1)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f, Writer(f) as w:
        schemas = {}

        def put(topic, msg, ns):
            kind = known[topic]
            if kind not in schemas:
                schemas[kind] = w.register_msgdef(kind, schema_text(kind))
            w.write_message(topic, schemas[kind], msg, log_time=int(ns), publish_time=int(ns))

        ns0 = int(stamps[0]) if len(stamps) else int(start_ns)
        if "/tf_static" in topics:
            # latched like a recorded /tf_static: its channel carries the QoS metadata, which
            # mcap_ros2's Writer cannot set, so the channel is registered on its MCAP writer
            schemas[TF] = w.register_msgdef(TF, schema_text(TF))
            w._channel_ids["/tf_static"] = w._writer.register_channel(
                topic="/tf_static",
                message_encoding="cdr",
                schema_id=schemas[TF].id,
                metadata={"offered_qos_profiles": _LATCHED_QOS},
            )
        for topic, msg in msgs.static(ns0, topics):
            put(topic, msg, ns0)
        frames_out = {
            cam: (np.rint(np.asarray(ti, float) * 1e9).astype(np.int64) + int(start_ns), fr)
            for cam, (ti, fr) in images.items()
        }
        next_img = dict.fromkeys(frames_out, 0)
        for k, ns in enumerate(stamps):
            for topic, msg in msgs.step(int(ns), step_row(arrays, k), topics):
                put(topic, msg, ns)
            # images up to the next step's stamp, in time order with the rest
            end = stamps[k + 1] if k + 1 < len(stamps) else np.iinfo(np.int64).max
            for cam, (ti, fr) in frames_out.items():
                while next_img[cam] < len(ti) and ti[next_img[cam]] < end:
                    j = next_img[cam]
                    if image_topic(cam) in topics:
                        put(*msgs.image(cam, int(ti[j]), fr[j]), int(ti[j]))
                    next_img[cam] += 1
    log.info("MCAP written to %s (%d steps)", path, len(t))
    return path


def render_images(run: RunFolder, cam: str, every: int):
    """``(t, frames)`` of camera ``cam`` ("C_L", "C_G", or "C_L{i}": arm ``i``'s C_L)
    re-rendered from the stored ``q`` every ``every`` steps with the planar renderer (what
    :mod:`tdacm.viz.rerun_log` shows); a C_L sees its arm's scene, C_G the first arm's."""
    from ..vision import PlanarRenderer

    t = np.asarray(run.arrays["t"], float)
    q = np.asarray(run.arrays["q"], float).reshape(len(t), -1)
    msgs = messages_of(run)
    idx = np.arange(0, len(t), every)
    renderer = PlanarRenderer(msgs.camera_view(cam, q[0])[2])
    try:
        frames = []
        for k in idx:
            camera, g, _ = msgs.camera_view(cam, q[k])
            frames.append(np.ascontiguousarray(renderer.render(camera, g)[:, :, :3]))
    finally:
        renderer.close()
    return t[idx], np.asarray(frames, dtype=np.uint8)

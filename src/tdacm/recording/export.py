"""Export a ``tdacm run`` folder as an MCAP recording in standard ROS 2 message types.

The file is written with the PyPI libraries ``mcap`` and ``mcap-ros2-support`` (no ROS
installation): every schema is the ROS 2 ``.msg`` text (:mod:`.msgdefs`, encoding ``ros2msg``)
and every message is CDR, so Foxglove opens the file and ``ros2 bag play`` replays it. Header
stamps and log times are the run's ``t`` (nanoseconds, plus ``start_ns``).

Default topics (:data:`DEFAULT_TOPICS`; the table with the fields is in docs/recordings.md),
one message per control step unless noted:

* ``/tf`` (``tf2_msgs/msg/TFMessage``): ``world -> base_link`` (the drone, eq. (1)) and the
  rod chain ``rod_base -> rod_1 -> ... -> rod_{n-1} -> tip``, cross-sections at
  ``s_k = k L / n`` (eq. (5)-(7)), ``tip`` the model's tip pose ``g_L``;
* ``/tf_static`` (once, latched): ``base_link -> rod_base`` (``g_a^b``), ``tip ->
  C_L_optical`` and ``base_link -> C_G_optical`` (the camera mounts), ``world -> target``;
* ``geometry_msgs/msg/PoseStamped``: ``/tdacm/drone/pose``, ``/tdacm/tip/pose`` (in
  ``world``), and once ``/tdacm/target/pose`` and ``/tdacm/goal/camera_pose`` (C_L at ``q*``);
* ``sensor_msgs/msg/JointState``: ``/tdacm/strains`` (position ``q_s``, velocity their rates,
  effort the commanded generalized force ``tau_s``), ``/tdacm/tendons`` (effort the tensions,
  the columns of ``u`` after the thrusts; position the tendon path lengths),
  ``/tdacm/rotors`` (effort the thrusts; flying base only);
* ``std_msgs/msg/Float64MultiArray``: ``/tdacm/servo/features``, ``.../feature_error``,
  ``.../points_local``; ``std_msgs/msg/Float64``: ``/tdacm/servo/rmse``;
* ``sensor_msgs/msg/CameraInfo``: ``/tdacm/C_L/camera_info``, ``/tdacm/C_G/camera_info``;
  ``sensor_msgs/msg/Image``: ``/tdacm/C_L/image_raw``, ``/tdacm/C_G/image_raw`` (when frames
  are given or rendered).

A robot with several arms (``[[robot.arms]]``) adds each arm's camera frame on its rod's tip
(:func:`camera_frame`), its target (:func:`target_frame`) and the topics of
:func:`arm_topics` (arm ``i >= 1`` under ``/tdacm/arm{i}/``: tip and target poses, goal camera
pose, detected points, camera info, images; every arm's ``/tdacm/arm{i}/servo/rmse``).

A ``std_msgs/msg/Float64MultiArray`` names its components in its (last) dimension's label,
comma-separated (``"p_phi,p_theta,p_psi,p_x,p_y,p_z"``); the names are those of
``timeseries.csv`` (:func:`tdacm.sim.outputs.columns`). A run folder holds no raw camera
images (``video.mp4`` is the captioned composite), so images are exported when given
(``images=``) or re-rendered from the stored ``q`` by the planar renderer (``render_every=``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._extras import require
from ..vision.mounts import tip_camera_pose
from .msgdefs import schema_text

log = logging.getLogger(__name__)

WORLD, BASE, ROD_BASE, TIP = "world", "base_link", "rod_base", "tip"
C_L_FRAME, C_G_FRAME, TARGET_FRAME = "C_L_optical", "C_G_optical", "target"

TF = "tf2_msgs/msg/TFMessage"
POSE = "geometry_msgs/msg/PoseStamped"
JOINTS = "sensor_msgs/msg/JointState"
ARRAY = "std_msgs/msg/Float64MultiArray"
FLOAT = "std_msgs/msg/Float64"
INFO = "sensor_msgs/msg/CameraInfo"
IMAGE = "sensor_msgs/msg/Image"

#: topic -> message type (the table of the module docstring).
DEFAULT_TOPICS = {
    "/tf": TF,
    "/tf_static": TF,
    "/tdacm/drone/pose": POSE,
    "/tdacm/tip/pose": POSE,
    "/tdacm/target/pose": POSE,
    "/tdacm/goal/camera_pose": POSE,
    "/tdacm/strains": JOINTS,
    "/tdacm/tendons": JOINTS,
    "/tdacm/rotors": JOINTS,
    "/tdacm/servo/features": ARRAY,
    "/tdacm/servo/feature_error": ARRAY,
    "/tdacm/servo/points_local": ARRAY,
    "/tdacm/servo/rmse": FLOAT,
    "/tdacm/C_L/camera_info": INFO,
    "/tdacm/C_G/camera_info": INFO,
    "/tdacm/C_L/image_raw": IMAGE,
    "/tdacm/C_G/image_raw": IMAGE,
}


def arm_topics(n_arms: int) -> dict:
    """The topics of the arms after the first of a robot with ``n_arms`` arms (arm ``i``
    under ``/tdacm/arm{i}/``; arm 0 keeps the topics of :data:`DEFAULT_TOPICS`), and with
    several arms each arm's ``/tdacm/arm{i}/servo/rmse`` (``/tdacm/servo/rmse`` is then the
    largest over the arms)."""
    out = {}
    for i in range(1, n_arms):
        pre = f"/tdacm/arm{i}"
        out.update({
            f"{pre}/tip/pose": POSE,
            f"{pre}/target/pose": POSE,
            f"{pre}/goal/camera_pose": POSE,
            f"{pre}/servo/points_local": ARRAY,
            f"{pre}/C_L/camera_info": INFO,
            f"{pre}/C_L/image_raw": IMAGE,
        })  # fmt: skip
    if n_arms > 1:
        out.update({f"/tdacm/arm{i}/servo/rmse": FLOAT for i in range(n_arms)})
    return out


def camera_frame(arm: int) -> str:
    """The optical frame of arm ``arm``'s C_L (``C_L_optical`` for arm 0)."""
    return C_L_FRAME if arm == 0 else f"arm{arm}_{C_L_FRAME}"


def target_frame(arm: int) -> str:
    """The frame of arm ``arm``'s target (``target`` for arm 0)."""
    return TARGET_FRAME if arm == 0 else f"arm{arm}_{TARGET_FRAME}"


def _image_topic(cam: str) -> str:
    """The image topic of camera key ``cam``: ``C_L``, ``C_G``, or ``C_L{i}`` (arm ``i``)."""
    if cam in ("C_L", "C_G"):
        return f"/tdacm/{cam}/image_raw"
    return f"/tdacm/arm{int(cam[3:])}/C_L/image_raw"


#: Float64MultiArray topic -> series of ``timeseries.npz``.
ARRAY_SERIES = {
    "/tdacm/servo/features": "features",
    "/tdacm/servo/feature_error": "feature_error",
    "/tdacm/servo/points_local": "points_local",
}

#: Default number of rod intervals of ``/tf``: section frames at ``s_k = k L / n``.
DEFAULT_SECTIONS = 10

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


# ------------------------------------------------------------------ message builders
def _stamp(ns: int) -> dict:
    return {"sec": int(ns // 1_000_000_000), "nanosec": int(ns % 1_000_000_000)}


def _header(ns: int, frame: str) -> dict:
    return {"stamp": _stamp(ns), "frame_id": frame}


def _quat(r: np.ndarray) -> list[float]:
    """``[x, y, z, w]`` of a rotation matrix (ROS order)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_quat().tolist()


def _transform(ns: int, parent: str, child: str, g: np.ndarray) -> dict:
    x, y, z, w = _quat(g[:3, :3])
    p = g[:3, 3]
    return {
        "header": _header(ns, parent),
        "child_frame_id": child,
        "transform": {
            "translation": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
            "rotation": {"x": x, "y": y, "z": z, "w": w},
        },
    }


def _pose(ns: int, frame: str, g: np.ndarray) -> dict:
    x, y, z, w = _quat(g[:3, :3])
    p = g[:3, 3]
    return {
        "header": _header(ns, frame),
        "pose": {
            "position": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
            "orientation": {"x": x, "y": y, "z": z, "w": w},
        },
    }


def _array(values: np.ndarray, names) -> dict:
    """``std_msgs/Float64MultiArray``: one dimension labelled with the component names, or,
    for a matrix (the image points, 4 x 2), one dimension per axis (row-major strides), the
    last one labelled with the column names (``"x,y"``)."""
    v = np.asarray(values, float)
    if v.ndim <= 1:
        dims = [{"label": ",".join(names), "size": v.size, "stride": v.size}]
    else:
        labels = ["row"] * (v.ndim - 1) + [",".join(_COLUMN_LABELS.get(v.shape[-1], ()))]
        strides = np.cumprod(v.shape[::-1])[::-1]
        dims = [{"label": lab, "size": int(n), "stride": int(st)}
                for lab, n, st in zip(labels, v.shape, strides, strict=True)]  # fmt: skip
    return {"layout": {"dim": dims, "data_offset": 0}, "data": v.ravel().tolist()}


_COLUMN_LABELS = {2: ("x", "y")}  # image points: normalized (x, y)


def camera_info(ns: int, frame: str, cam) -> dict:
    """``sensor_msgs/CameraInfo`` of a :class:`~tdacm.vision.PinholeCamera` (OpenCV model:
    ``plumb_bob`` for up to 5 coefficients, ``rational_polynomial`` for 8)."""
    d = list(cam.distortion)
    if len(d) <= 5:
        model, d = "plumb_bob", d + [0.0] * (5 - len(d))
    elif len(d) == 8:
        model = "rational_polynomial"
    else:
        model = "opencv"  # 12 or 14 OpenCV coefficients: no ROS name
    fx, fy, cx, cy = float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)
    return {
        "header": _header(ns, frame),
        "height": int(cam.height),
        "width": int(cam.width),
        "distortion_model": model,
        "d": [float(x) for x in d],
        "k": [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "p": [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        "binning_x": 0,
        "binning_y": 0,
        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    }


_ENCODINGS = {1: "mono8", 3: "rgb8", 4: "rgba8"}


def _checked_frame(img) -> np.ndarray:
    a = np.asarray(img)
    if (
        a.dtype != np.uint8
        or a.ndim not in (2, 3)
        or (a.ndim == 3 and a.shape[2] not in _ENCODINGS)
    ):
        raise ExportError(
            f"images: a frame must be uint8 (H, W), (H, W, 3) or (H, W, 4), got {a.dtype} {a.shape}"
        )
    return a


def image(ns: int, frame: str, img) -> dict:
    """``sensor_msgs/Image`` of an 8-bit image (H, W) ``mono8``, (H, W, 3) ``rgb8`` or
    (H, W, 4) ``rgba8``."""
    a = _checked_frame(img)
    ch = 1 if a.ndim == 2 else a.shape[2]
    return {
        "header": _header(ns, frame),
        "height": int(a.shape[0]),
        "width": int(a.shape[1]),
        "encoding": _ENCODINGS[ch],
        "is_bigendian": 0,
        "step": int(a.shape[1] * ch),
        "data": np.ascontiguousarray(a).tobytes(),
    }


def _series_names(arrays: dict, floating: bool) -> dict:
    """Series -> component names, as in ``timeseries.csv`` (one source for the names)."""
    from ..sim.outputs import columns

    _, info = columns(arrays, floating)
    names: dict[str, list[str]] = {}
    for c in info:
        names.setdefault(c["series"], []).append(c["name"])
    return names


def _section_frames(system, n_sections: int):
    """Per rod: ``(prefix, [(frame, parent, s), ...])`` of the section frames, the last one
    the tip (``s = L``)."""
    out = []
    for r, arm in enumerate(system.arms):
        pre = "rod" if system.n_rods == 1 else f"rod{r + 1}"
        tip = TIP if r == 0 else f"{pre}_tip"
        base = ROD_BASE if system.n_rods == 1 else f"{pre}_base"
        frames, parent = [], base
        for k in range(1, n_sections + 1):
            name = tip if k == n_sections else f"{pre}_{k}"
            frames.append((name, parent, arm.length * k / n_sections))
            parent = name
        out.append((base, frames))
    return out


def _inv(g: np.ndarray) -> np.ndarray:
    h = np.eye(4)
    h[:3, :3] = g[:3, :3].T
    h[:3, 3] = -g[:3, :3].T @ g[:3, 3]
    return h


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
    arms = _arms(run)
    known = {**DEFAULT_TOPICS, **arm_topics(len(arms))}
    topics = set(known if topics is None else topics)
    unknown = sorted(topics - set(known))
    if unknown:
        raise ExportError(f"topics: unknown {unknown[0]!r} (known: {', '.join(known)})")
    if int(n_sections) < 1:
        raise ExportError(f"n_sections must be a positive integer, got {n_sections!r}")
    if render_every is not None and int(render_every) < 1:
        raise ExportError(f"render_every must be a positive integer, got {render_every!r}")
    images = dict(images or {})
    cams = ["C_L", "C_G", *(f"C_L{i}" for i in range(1, len(arms)))]
    bad = sorted(set(images) - set(cams))
    if bad:
        raise ExportError(f"images: unknown camera {bad[0]!r} ({', '.join(cams)})")
    for cam, given in images.items():
        ti, fr = (np.asarray(x) for x in given)
        if ti.ndim != 1 or len(fr) != len(ti) or np.any(np.diff(ti) < 0):
            raise ExportError(f"images[{cam!r}]: give (t, frames) with increasing t, one per "
                              f"frame (got {ti.shape} times, {len(fr)} frames)")  # fmt: skip
        for f in fr:  # before the file is opened: no half-written recording
            _checked_frame(f)
    a, robot, system = run.arrays, run.robot, run.robot.system
    t = np.asarray(a["t"], float)
    q = np.asarray(a["q"], float).reshape(len(t), -1)
    stamps = np.rint(t * 1e9).astype(np.int64) + int(start_ns)
    names = _series_names(a, system.floating)
    sections = _section_frames(system, int(n_sections))
    n_base = system.n - system.n_s
    m_u = system.n_u - system.n_a
    if render_every is not None:
        for cam in cams:
            if cam not in images and _image_topic(cam) in topics:
                images[cam] = render_images(run, cam, int(render_every))
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
            static = [_transform(ns0, BASE, rb, arm.attachment)
                      for (rb, _), arm in zip(sections, system.arms, strict=True)]  # fmt: skip
            for i, arm in enumerate(arms):  # each arm's C_L on its rod's tip, its target
                tip = sections[arm.rod][1][-1][0]
                static.append(_transform(ns0, tip, camera_frame(i), arm.tip_mount))
            static.append(_transform(ns0, BASE, C_G_FRAME, robot.drone_mount))
            static += [_transform(ns0, WORLD, target_frame(i), arm.scene.target_pose)
                       for i, arm in enumerate(arms)]  # fmt: skip
            put("/tf_static", {"transforms": static}, ns0)
        for i, arm in enumerate(arms):
            pre = "/tdacm" if i == 0 else f"/tdacm/arm{i}"
            if f"{pre}/target/pose" in topics:
                put(f"{pre}/target/pose", _pose(ns0, WORLD, arm.scene.target_pose), ns0)
            if f"{pre}/goal/camera_pose" in topics:
                goal = tip_camera_pose(system, run.q_star, arm.tip_mount, arm.rod)
                put(f"{pre}/goal/camera_pose", _pose(ns0, WORLD, goal), ns0)
        frames_out = {
            cam: (np.rint(np.asarray(ti, float) * 1e9).astype(np.int64) + int(start_ns), fr)
            for cam, (ti, fr) in images.items()
        }
        next_img = dict.fromkeys(frames_out, 0)
        qd = np.asarray(a["qd"], float).reshape(len(t), -1) if "qd" in a else None
        tau = np.asarray(a["tau"], float).reshape(len(t), -1) if "tau" in a else None
        u = np.asarray(a["u"], float).reshape(len(t), -1) if "u" in a else None
        local = rmse_arms = None
        if len(arms) > 1 and "points_local_arms" in a:
            local = np.asarray(a["points_local_arms"], float).reshape(len(t), len(arms), 4, 2)
        if len(arms) > 1 and "rmse_arms" in a:
            rmse_arms = np.asarray(a["rmse_arms"], float).reshape(len(t), len(arms))
        for k, ns in enumerate(stamps):
            qk = q[k]
            gb = system.base_pose(qk)
            if "/tf" in topics:
                tfs = [_transform(ns, WORLD, BASE, gb)]
                for r, (_, frames) in enumerate(sections):
                    prev = gb @ system.arms[r].attachment
                    for j, (name, parent, s) in enumerate(frames):
                        last = j == len(frames) - 1  # the tip: the model's own tip pose
                        g = system.tip_pose(qk, r) if last else system.pose(qk, s, r)
                        tfs.append(_transform(ns, parent, name, _inv(prev) @ g))
                        prev = g
                put("/tf", {"transforms": tfs}, ns)
            if "/tdacm/drone/pose" in topics:
                put("/tdacm/drone/pose", _pose(ns, WORLD, gb), ns)
            for i, arm in enumerate(arms):
                topic = "/tdacm/tip/pose" if i == 0 else f"/tdacm/arm{i}/tip/pose"
                if topic in topics:
                    put(topic, _pose(ns, WORLD, system.tip_pose(qk, arm.rod)), ns)
            if "/tdacm/strains" in topics:
                put("/tdacm/strains", {
                    "header": _header(ns, ""),
                    "name": names["q"][n_base:],
                    "position": qk[n_base:].tolist(),
                    "velocity": [] if qd is None else qd[k, n_base:].tolist(),
                    "effort": [] if tau is None else tau[k, n_base:].tolist(),
                }, ns)  # fmt: skip
            if u is not None and "/tdacm/tendons" in topics:
                put("/tdacm/tendons", {
                    "header": _header(ns, ""),
                    "name": names["u"][m_u:],
                    "position": system.tendon_lengths(qk).tolist(),
                    "velocity": [],
                    "effort": u[k, m_u:].tolist(),
                }, ns)  # fmt: skip
            if u is not None and m_u and "/tdacm/rotors" in topics:
                put("/tdacm/rotors", {"header": _header(ns, ""), "name": names["u"][:m_u],
                                      "position": [], "velocity": [],
                                      "effort": u[k, :m_u].tolist()}, ns)  # fmt: skip
            for topic, key in ARRAY_SERIES.items():
                if topic in topics and key in a:
                    put(topic, _array(a[key][k], names[key]), ns)
            if "/tdacm/servo/rmse" in topics and "rmse" in a:
                put("/tdacm/servo/rmse", {"data": float(a["rmse"][k])}, ns)
            for i in range(len(arms) if len(arms) > 1 else 0):
                topic = f"/tdacm/arm{i}/servo/points_local"
                if i > 0 and topic in topics and local is not None:
                    put(topic, _array(local[k, i], names["points_local"]), ns)
                topic = f"/tdacm/arm{i}/servo/rmse"
                if topic in topics and rmse_arms is not None:
                    put(topic, {"data": float(rmse_arms[k, i])}, ns)
            infos = [(f"/tdacm/arm{i}/C_L" if i else "/tdacm/C_L", camera_frame(i),
                      arm.local_camera) for i, arm in enumerate(arms)]  # fmt: skip
            infos.append(("/tdacm/C_G", C_G_FRAME, robot.global_camera))
            for pre, fr, c in infos:
                if f"{pre}/camera_info" in topics:
                    put(f"{pre}/camera_info", camera_info(ns, fr, c), ns)
            # images up to the next step's stamp, in time order with the rest
            end = stamps[k + 1] if k + 1 < len(stamps) else np.iinfo(np.int64).max
            for cam, (ti, fr) in frames_out.items():
                topic = _image_topic(cam)
                while next_img[cam] < len(ti) and ti[next_img[cam]] < end:
                    j = next_img[cam]
                    if topic in topics:
                        frame = C_G_FRAME if cam == "C_G" else camera_frame(int(cam[3:] or 0))
                        put(topic, image(int(ti[j]), frame, fr[j]), int(ti[j]))
                    next_img[cam] += 1
    log.info("MCAP written to %s (%d steps)", path, len(t))
    return path


@dataclass(frozen=True)
class _Arm:
    """One arm as the export writes it: its rod, C_L, mount and scene (its target)."""

    rod: int
    local_camera: object
    tip_mount: np.ndarray
    scene: object


def _arms(run: RunFolder) -> list[_Arm]:
    """The arms of the run's robot (one for the single-arm form)."""
    r = run.robot
    if not r.arms:
        return [_Arm(0, r.local_camera, r.tip_mount, run.scene)]
    return [_Arm(a.rod, a.local_camera, a.tip_mount, sc)
            for a, sc in zip(r.arms, run.scenes, strict=True)]  # fmt: skip


def render_images(run: RunFolder, cam: str, every: int):
    """``(t, frames)`` of camera ``cam`` ("C_L", "C_G", or "C_L{i}": arm ``i``'s C_L)
    re-rendered from the stored ``q`` every ``every`` steps with the planar renderer (what
    :mod:`tdacm.viz.rerun_log` shows); a C_L sees its arm's scene, C_G the first arm's."""
    from ..vision import PlanarRenderer

    t = np.asarray(run.arrays["t"], float)
    q = np.asarray(run.arrays["q"], float).reshape(len(t), -1)
    r, s = run.robot, run.robot.system
    arm = _arms(run)[0 if cam in ("C_L", "C_G") else int(cam[3:])]
    camera = r.global_camera if cam == "C_G" else arm.local_camera
    idx = np.arange(0, len(t), every)
    renderer = PlanarRenderer(run.scene if cam == "C_G" else arm.scene)
    try:
        frames = []
        for k in idx:
            g = (
                s.base_pose(q[k]) @ r.drone_mount
                if cam == "C_G"
                else tip_camera_pose(s, q[k], arm.tip_mount, arm.rod)
            )
            frames.append(np.ascontiguousarray(renderer.render(camera, g)[:, :, :3]))
    finally:
        renderer.close()
    return t[idx], np.asarray(frames, dtype=np.uint8)

"""The robot at one control step as ROS 2 messages: what ``tdacm export`` writes to an MCAP file
and what the live server (:mod:`.server`) publishes as the run goes, from one set of builders
(:class:`RobotMessages`), so the topics, message types and frames of both are the same and one
Foxglove layout serves both.

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
* ``visualization_msgs/msg/ImageMarker``: ``/tdacm/C_L/features``, the detected points in
  C_L's pixels (the image panel draws them over ``/tdacm/C_L/image_raw``);
* ``sensor_msgs/msg/CameraInfo``: ``/tdacm/C_L/camera_info``, ``/tdacm/C_G/camera_info``;
  ``sensor_msgs/msg/Image``: ``/tdacm/C_L/image_raw``, ``/tdacm/C_G/image_raw`` (when frames
  are given or rendered).

A robot with several arms (``[[robot.arms]]``) adds each arm's camera frame on its rod's tip
(:func:`camera_frame`), its target (:func:`target_frame`) and the topics of
:func:`arm_topics` (arm ``i >= 1`` under ``/tdacm/arm{i}/``: tip and target poses, goal camera
pose, detected points, camera info, images; every arm's ``/tdacm/arm{i}/servo/rmse``).

A ``std_msgs/msg/Float64MultiArray`` names its components in its (last) dimension's label,
comma-separated (``"p_phi,p_theta,p_psi,p_x,p_y,p_z"``); the names are those of
``timeseries.csv`` (:func:`tdacm.sim.outputs.columns`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..vision.mounts import tip_camera_pose

WORLD, BASE, ROD_BASE, TIP = "world", "base_link", "rod_base", "tip"
C_L_FRAME, C_G_FRAME, TARGET_FRAME = "C_L_optical", "C_G_optical", "target"

TF = "tf2_msgs/msg/TFMessage"
POSE = "geometry_msgs/msg/PoseStamped"
JOINTS = "sensor_msgs/msg/JointState"
ARRAY = "std_msgs/msg/Float64MultiArray"
FLOAT = "std_msgs/msg/Float64"
INFO = "sensor_msgs/msg/CameraInfo"
IMAGE = "sensor_msgs/msg/Image"
MARKER = "visualization_msgs/msg/ImageMarker"

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
    "/tdacm/C_L/features": MARKER,
    "/tdacm/C_L/camera_info": INFO,
    "/tdacm/C_G/camera_info": INFO,
    "/tdacm/C_L/image_raw": IMAGE,
    "/tdacm/C_G/image_raw": IMAGE,
}

#: The topics sent once at the start (and again to a client that subscribes later).
STATIC_TOPICS = ("/tf_static", "/tdacm/target/pose", "/tdacm/goal/camera_pose")


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
            f"{pre}/C_L/features": MARKER,
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


def image_topic(cam: str) -> str:
    """The image topic of camera key ``cam``: ``C_L``, ``C_G``, or ``C_L{i}`` (arm ``i``)."""
    if cam in ("C_L", "C_G"):
        return f"/tdacm/{cam}/image_raw"
    return f"/tdacm/arm{int(cam[3:])}/C_L/image_raw"


def cameras(n_arms: int) -> list[str]:
    """The camera keys of a robot of ``n_arms`` arms: ``C_L``, ``C_G``, then ``C_L{i}``."""
    return ["C_L", "C_G", *(f"C_L{i}" for i in range(1, n_arms))]


#: Float64MultiArray topic -> series of ``timeseries.npz``.
ARRAY_SERIES = {
    "/tdacm/servo/features": "features",
    "/tdacm/servo/feature_error": "feature_error",
    "/tdacm/servo/points_local": "points_local",
}

#: The series a step's row may hold (:meth:`RobotMessages.step`): the run's log row.
ROW_SERIES = ("t", "q", "qd", "tau", "u", *ARRAY_SERIES.values(), "rmse",
              "points_local_arms", "rmse_arms")  # fmt: skip

#: Default number of rod intervals of ``/tf``: section frames at ``s_k = k L / n``.
DEFAULT_SECTIONS = 10

#: Size (pixels) and colour (RGBA) of the detected points drawn on C_L's image.
FEATURE_MARKER_SIZE = 8.0
FEATURE_MARKER_RGBA = (1.0, 0.15, 0.15, 1.0)


class FrameError(ValueError):
    """A camera frame that is not an 8-bit image; the message says why."""


# ------------------------------------------------------------------ message builders
def stamp(ns: int) -> dict:
    return {"sec": int(ns // 1_000_000_000), "nanosec": int(ns % 1_000_000_000)}


def header(ns: int, frame: str) -> dict:
    return {"stamp": stamp(ns), "frame_id": frame}


def _quat(r: np.ndarray) -> list[float]:
    """``[x, y, z, w]`` (ROS order, ``w >= 0``) of a rotation matrix, by Shepperd's method:
    from the largest of ``1 + trace`` and ``1 + 2 r_ii - trace`` (four times the square of a
    component), so no division by a small number. Scalar arithmetic: a publish builds a few
    dozen of these, where scipy's ``Rotation`` costs a millisecond each."""
    r00, r01, r02 = float(r[0, 0]), float(r[0, 1]), float(r[0, 2])
    r10, r11, r12 = float(r[1, 0]), float(r[1, 1]), float(r[1, 2])
    r20, r21, r22 = float(r[2, 0]), float(r[2, 1]), float(r[2, 2])
    tr = r00 + r11 + r22
    k = max(range(4), key=(tr, r00, r11, r22).__getitem__)
    if k == 0:
        f = 2.0 * math.sqrt(1.0 + tr)
        x, y, z, w = (r21 - r12) / f, (r02 - r20) / f, (r10 - r01) / f, f / 4
    elif k == 1:
        f = 2.0 * math.sqrt(1.0 + 2.0 * r00 - tr)
        x, y, z, w = f / 4, (r01 + r10) / f, (r02 + r20) / f, (r21 - r12) / f
    elif k == 2:
        f = 2.0 * math.sqrt(1.0 + 2.0 * r11 - tr)
        x, y, z, w = (r01 + r10) / f, f / 4, (r12 + r21) / f, (r02 - r20) / f
    else:
        f = 2.0 * math.sqrt(1.0 + 2.0 * r22 - tr)
        x, y, z, w = (r02 + r20) / f, (r12 + r21) / f, f / 4, (r10 - r01) / f
    n = math.sqrt(x * x + y * y + z * z + w * w) * (1.0 if w >= 0 else -1.0)
    return [x / n, y / n, z / n, w / n]


def transform(ns: int, parent: str, child: str, g: np.ndarray) -> dict:
    x, y, z, w = _quat(g[:3, :3])
    p = g[:3, 3]
    return {
        "header": header(ns, parent),
        "child_frame_id": child,
        "transform": {
            "translation": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
            "rotation": {"x": x, "y": y, "z": z, "w": w},
        },
    }


def pose(ns: int, frame: str, g: np.ndarray) -> dict:
    x, y, z, w = _quat(g[:3, :3])
    p = g[:3, 3]
    return {
        "header": header(ns, frame),
        "pose": {
            "position": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
            "orientation": {"x": x, "y": y, "z": z, "w": w},
        },
    }


def array(values: np.ndarray, names) -> dict:
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
        "header": header(ns, frame),
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


def checked_frame(img) -> np.ndarray:
    """``img`` as an array if it is an 8-bit (H, W), (H, W, 3) or (H, W, 4) image, else
    :class:`FrameError`."""
    a = np.asarray(img)
    if (
        a.dtype != np.uint8
        or a.ndim not in (2, 3)
        or (a.ndim == 3 and a.shape[2] not in _ENCODINGS)
    ):
        raise FrameError(
            f"images: a frame must be uint8 (H, W), (H, W, 3) or (H, W, 4), got {a.dtype} {a.shape}"
        )
    return a


def image(ns: int, frame: str, img) -> dict:
    """``sensor_msgs/Image`` of an 8-bit image (H, W) ``mono8``, (H, W, 3) ``rgb8`` or
    (H, W, 4) ``rgba8``."""
    a = checked_frame(img)
    ch = 1 if a.ndim == 2 else a.shape[2]
    return {
        "header": header(ns, frame),
        "height": int(a.shape[0]),
        "width": int(a.shape[1]),
        "encoding": _ENCODINGS[ch],
        "is_bigendian": 0,
        "step": int(a.shape[1] * ch),
        "data": np.ascontiguousarray(a).tobytes(),
    }


def feature_marker(ns: int, frame: str, cam, points) -> dict:
    """``visualization_msgs/ImageMarker`` (``POINTS``) of the detected points ``points`` (4, 2)
    (normalized C_L coordinates, NaN when not detected) in the pixels of camera ``cam``
    (distorted as the image is): what an image panel draws over the camera's image."""
    p = np.asarray(points, float).reshape(-1, 2)
    p = p[np.all(np.isfinite(p), axis=1)]
    uv = cam.denormalize(p) if len(p) else np.zeros((0, 2))
    r, g, b, a = FEATURE_MARKER_RGBA
    color = {"r": r, "g": g, "b": b, "a": a}
    return {
        "header": header(ns, frame),
        "ns": "features",
        "id": 0,
        "type": 4,  # POINTS
        "action": 0,  # ADD
        "position": {"x": 0.0, "y": 0.0, "z": 0.0},
        "scale": FEATURE_MARKER_SIZE,
        "outline_color": color,
        "filled": 1,
        "fill_color": color,
        "lifetime": {"sec": 0, "nanosec": 0},
        "points": [{"x": float(u), "y": float(v), "z": 0.0} for u, v in uv],
        "outline_colors": [color for _ in uv],
    }


def series_names(arrays: dict, floating: bool) -> dict:
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


@dataclass(frozen=True)
class Arm:
    """One arm as the messages show it: its rod, C_L, mount and scene (its target)."""

    rod: int
    local_camera: object
    tip_mount: np.ndarray
    scene: object


def robot_arms(robot, scene, scenes=()) -> list[Arm]:
    """The arms of ``robot`` (one for the single-arm form, on ``scene``; several arms on their
    ``scenes``, as :func:`tdacm.sim.assemble.build_world` returns them)."""
    if not robot.arms:
        return [Arm(0, robot.local_camera, robot.tip_mount, scene)]
    return [Arm(a.rod, a.local_camera, a.tip_mount, sc)
            for a, sc in zip(robot.arms, scenes, strict=True)]  # fmt: skip


class RobotMessages:
    """The ROS 2 messages of one robot, step by step (module docstring): ``static`` once,
    ``step`` per control step from the step's row of logged series, ``image`` per camera
    frame. Each returns ``[(topic, message dict), ...]`` in the order they are written, only
    for the topics asked for.

    ``robot``: a :class:`~tdacm.sim.robot.Robot`; ``arms``: :func:`robot_arms`; ``q_star``:
    the desired configuration; ``names``: :func:`series_names` of the run's series;
    ``n_sections``: rod intervals of ``/tf``."""

    def __init__(self, robot, arms, q_star, names: dict, n_sections: int = DEFAULT_SECTIONS):
        self.robot = robot
        self.system = s = robot.system
        self.arms = list(arms)
        self.q_star = np.asarray(q_star, float)
        self.names = names
        self.sections = _section_frames(s, int(n_sections))
        self.n_base = s.n - s.n_s
        self.m_u = s.n_u - s.n_a
        #: topic -> message type: every topic of this robot
        self.topics = {**DEFAULT_TOPICS, **arm_topics(len(self.arms))}
        self.cameras = cameras(len(self.arms))

    @classmethod
    def of_world(cls, world, n_sections: int = DEFAULT_SECTIONS) -> RobotMessages:
        """The messages of a built world (:class:`tdacm.sim.assemble.World`), its series
        named as a run of it logs them."""
        robot = world.robot
        s = robot.system
        one = {"t": np.zeros(1), "q": np.zeros((1, s.n)), "u": np.zeros((1, s.n_u)),
               "features": np.zeros((1, 6)), "feature_error": np.zeros((1, 6)),
               "points_local": np.zeros((1, 4, 2))}  # fmt: skip
        arms = robot_arms(robot, world.scene, world.scenes)
        return cls(robot, arms, world.q_star, series_names(one, s.floating), n_sections)

    def static(self, ns: int, topics) -> list:
        """The messages sent once: ``/tf_static`` (rod bases, camera mounts, targets), each
        arm's target pose and goal camera pose."""
        s, robot, out = self.system, self.robot, []
        if "/tf_static" in topics:
            static = [transform(ns, BASE, rb, arm.attachment)
                      for (rb, _), arm in zip(self.sections, s.arms, strict=True)]  # fmt: skip
            for i, arm in enumerate(self.arms):  # each arm's C_L on its rod's tip, its target
                tip = self.sections[arm.rod][1][-1][0]
                static.append(transform(ns, tip, camera_frame(i), arm.tip_mount))
            static.append(transform(ns, BASE, C_G_FRAME, robot.drone_mount))
            static += [transform(ns, WORLD, target_frame(i), arm.scene.target_pose)
                       for i, arm in enumerate(self.arms)]  # fmt: skip
            out.append(("/tf_static", {"transforms": static}))
        for i, arm in enumerate(self.arms):
            pre = "/tdacm" if i == 0 else f"/tdacm/arm{i}"
            if f"{pre}/target/pose" in topics:
                out.append((f"{pre}/target/pose", pose(ns, WORLD, arm.scene.target_pose)))
            if f"{pre}/goal/camera_pose" in topics:
                goal = tip_camera_pose(s, self.q_star, arm.tip_mount, arm.rod)
                out.append((f"{pre}/goal/camera_pose", pose(ns, WORLD, goal)))
        return out

    def step(self, ns: int, row: dict, topics) -> list:
        """The messages of one control step stamped ``ns`` from ``row``: the step's values of
        the logged series (:data:`ROW_SERIES`; ``q`` required, each other one optional: its
        topics are left out without it)."""
        s, names, out = self.system, self.names, []
        n_base, m_u = self.n_base, self.m_u
        qk = np.asarray(row["q"], float)
        gb = s.base_pose(qk)
        if "/tf" in topics:
            tfs = [transform(ns, WORLD, BASE, gb)]
            for r, (_, frames) in enumerate(self.sections):
                prev = gb @ s.arms[r].attachment
                for j, (name, parent, sk) in enumerate(frames):
                    last = j == len(frames) - 1  # the tip: the model's own tip pose
                    g = s.tip_pose(qk, r) if last else s.pose(qk, sk, r)
                    tfs.append(transform(ns, parent, name, _inv(prev) @ g))
                    prev = g
            out.append(("/tf", {"transforms": tfs}))
        if "/tdacm/drone/pose" in topics:
            out.append(("/tdacm/drone/pose", pose(ns, WORLD, gb)))
        for i, arm in enumerate(self.arms):
            topic = "/tdacm/tip/pose" if i == 0 else f"/tdacm/arm{i}/tip/pose"
            if topic in topics:
                out.append((topic, pose(ns, WORLD, s.tip_pose(qk, arm.rod))))
        qd, tau, u = row.get("qd"), row.get("tau"), row.get("u")
        if "/tdacm/strains" in topics:
            out.append(("/tdacm/strains", {
                "header": header(ns, ""),
                "name": names["q"][n_base:],
                "position": qk[n_base:].tolist(),
                "velocity": [] if qd is None else np.asarray(qd, float)[n_base:].tolist(),
                "effort": [] if tau is None else np.asarray(tau, float)[n_base:].tolist(),
            }))  # fmt: skip
        if u is not None:
            u = np.asarray(u, float)
            if "/tdacm/tendons" in topics:
                out.append(("/tdacm/tendons", {
                    "header": header(ns, ""),
                    "name": names["u"][m_u:],
                    "position": s.tendon_lengths(qk).tolist(),
                    "velocity": [],
                    "effort": u[m_u:].tolist(),
                }))  # fmt: skip
            if m_u and "/tdacm/rotors" in topics:
                out.append(("/tdacm/rotors", {"header": header(ns, ""), "name": names["u"][:m_u],
                                              "position": [], "velocity": [],
                                              "effort": u[:m_u].tolist()}))  # fmt: skip
        for topic, key in ARRAY_SERIES.items():
            if topic in topics and row.get(key) is not None:
                out.append((topic, array(row[key], names[key])))
        if "/tdacm/servo/rmse" in topics and row.get("rmse") is not None:
            out.append(("/tdacm/servo/rmse", {"data": float(row["rmse"])}))
        local, rmse_arms = row.get("points_local_arms"), row.get("rmse_arms")
        n_arms = len(self.arms)
        if n_arms > 1 and local is not None:
            local = np.asarray(local, float).reshape(n_arms, 4, 2)
        for i in range(n_arms if n_arms > 1 else 0):
            topic = f"/tdacm/arm{i}/servo/points_local"
            if i > 0 and topic in topics and local is not None:
                out.append((topic, array(local[i], names["points_local"])))
            topic = f"/tdacm/arm{i}/servo/rmse"
            if topic in topics and rmse_arms is not None:
                out.append((topic, {"data": float(np.ravel(rmse_arms)[i])}))
        for i, arm in enumerate(self.arms):
            pre = "/tdacm" if i == 0 else f"/tdacm/arm{i}"
            pts = row.get("points_local") if i == 0 else (None if local is None else local[i])
            if f"{pre}/C_L/features" in topics and pts is not None:
                out.append((f"{pre}/C_L/features",
                            feature_marker(ns, camera_frame(i), arm.local_camera, pts)))  # fmt: skip
        infos = [(f"/tdacm/arm{i}/C_L" if i else "/tdacm/C_L", camera_frame(i),
                  arm.local_camera) for i, arm in enumerate(self.arms)]  # fmt: skip
        infos.append(("/tdacm/C_G", C_G_FRAME, self.robot.global_camera))
        for pre, fr, c in infos:
            if f"{pre}/camera_info" in topics:
                out.append((f"{pre}/camera_info", camera_info(ns, fr, c)))
        return out

    def image(self, cam: str, ns: int, img) -> tuple:
        """``(topic, sensor_msgs/Image)`` of camera ``cam``'s frame ``img`` stamped ``ns``."""
        frame = C_G_FRAME if cam == "C_G" else camera_frame(int(cam[3:] or 0))
        return image_topic(cam), image(ns, frame, img)

    def camera_view(self, cam: str, q):
        """``(camera, pose in world, scene)`` of camera ``cam`` at configuration ``q``: a C_L
        sees its arm's scene, C_G the first arm's."""
        s, r = self.system, self.robot
        arm = self.arms[0 if cam in ("C_L", "C_G") else int(cam[3:])]
        if cam == "C_G":
            return r.global_camera, s.base_pose(q) @ r.drone_mount, self.arms[0].scene
        return arm.local_camera, tip_camera_pose(s, q, arm.tip_mount, arm.rod), arm.scene

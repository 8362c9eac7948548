"""3-D replay of a run folder (``tdacm replay RUN_DIR``): the drone, the rods' backbones (every
arm of a robot with several), each tip camera's frustum, each arm's target and box, and the
ground, animated with matplotlib and written to GIF or MP4.

Playback is real time by default (``speed = 1``): the frame count and the frame rate are chosen
so that the animation lasts ``duration / speed``; when ``max_frames`` or an explicit ``fps``
makes that impossible, the title states the actual speed. Views: ``"follow"`` (centred on the arm
in x and y, from the ground to above the drone) or ``"scene"`` (fixed, the whole motion and the
target).

GIF uses Pillow; MP4 uses :func:`tdacm.viz.video.write_video` (H.264 through imageio-ffmpeg,
else OpenCV), so nothing is downloaded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..sim.outputs import RunDirError

VIEWS = ("follow", "scene")


def _drone_arms(g_b, arm):
    """Segments of a '+' quadrotor in the inertial frame."""
    ends = np.array([[arm, 0, 0], [-arm, 0, 0], [0, arm, 0], [0, -arm, 0]])
    pts = (g_b[:3, :3] @ ends.T).T + g_b[:3, 3]
    return [(pts[0], pts[1]), (pts[2], pts[3])]


def _frustum(cam_pose, camera, depth=0.35):
    """Segments of a camera's viewing pyramid (apex at the camera, base at ``depth``)."""
    w, h = camera.width, camera.height
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)
    rays = np.column_stack(((corners[:, 0] - camera.cx) / camera.fx,
                            (corners[:, 1] - camera.cy) / camera.fy, np.ones(4)))  # fmt: skip
    base = (cam_pose[:3, :3] @ (depth * rays).T).T + cam_pose[:3, 3]
    apex = cam_pose[:3, 3]
    segs = [(apex, b) for b in base] + [(base[i], base[(i + 1) % 4]) for i in range(4)]
    return segs


def _box_edges(centre_xy, size):
    x0, y0 = centre_xy[0] - size / 2, centre_xy[1] - size / 2
    c = np.array([[x0 + dx * size, y0 + dy * size, dz * size] for dz in (0, 1)
                  for dx, dy in ((0, 0), (1, 0), (1, 1), (0, 1))])  # fmt: skip
    idx = [(i, (i + 1) % 4) for i in range(4)]
    return [(c[a + o], c[b + o]) for o in (0, 4) for a, b in idx] + [
        (c[i], c[i + 4]) for i in range(4)
    ]


def replay_frames(
    system,
    q_series,
    target_points=None,
    tip_mount=None,
    stride=1,
    size=(640, 520),
    title="",
    times=None,
    scene=None,
    view="scene",
    camera=None,
    captions=None,
    progress=None,
    arms=None,
):
    """RGB frames (list of HxWx3 uint8) of the arm moving along ``q_series[::stride]``.

    ``scene`` (a :class:`~tdacm.vision.SceneConfig`) adds the box and the ground; ``camera``
    (default C_L) the tip camera's frustum; ``times`` the simulated time per row of
    ``q_series`` (shown); ``captions`` one extra string per row (e.g. the mode);
    ``progress(done, total)`` is called per frame. ``arms`` (the
    :class:`~tdacm.viz._scene.ArmView` of each arm) draws every rod of the system with its
    own C_L frustum, target and box (``tip_mount``, ``camera``, ``target_points`` and
    ``scene`` are then unused); without it the system's rods are drawn, the frustum and the
    target on rod 0."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    if view not in VIEWS:
        raise ValueError(f"view must be one of {VIEWS}, got {view!r}")
    if camera is None:
        from ..vision import LOCAL_CAMERA as camera
    idx = np.arange(len(q_series))[::stride]
    qs = np.asarray(q_series)[idx]
    n_rods = system.n_rods
    # (frames, rods, points, 4, 4): every rod's backbone
    bbs = np.array([[system.backbone(q, 21, rod=r) for r in range(n_rods)] for q in qs])
    bases = np.array([system.base_pose(q) for q in qs])
    if arms is not None:  # per arm: (rod, mount, camera, target outline, scene)
        views = [(a.rod, a.tip_mount, a.local_camera, a.scene.target_points_world(), a.scene)
                 for a in arms]  # fmt: skip
    else:
        views = [(0, tip_mount, camera, target_points, scene)]
    pts = bbs[..., :3, 3].reshape(-1, 3)
    extra = [v[3] for v in views if v[3] is not None]
    allp = np.vstack([pts, bases[:, :3, 3], *extra])
    lo, hi = allp.min(0), allp.max(0)
    lo[2] = min(lo[2], 0.0)
    centre, half = 0.5 * (lo + hi), 0.5 * max(np.max(hi - lo), 1.0) + 0.2
    arm = getattr(system.base, "arm_length", 0.0) if system.floating else 0.0
    fig = plt.figure(figsize=(size[0] / 100, size[1] / 100), dpi=100)
    ax = fig.add_subplot(projection="3d")
    rod_colors = ["C1", "C4", "C5", "C6"]
    handles = [Line2D([], [], color="k", lw=2, label="drone")]
    for r in range(n_rods):
        label = "rod" if n_rods == 1 else f"rod {r} (arm {r})"
        handles.append(Line2D([], [], color=rod_colors[r % 4], lw=3, label=label))
    handles += [
        Line2D([], [], color="C2", lw=1, label="C_L frustum" + ("s" if len(views) > 1 else "")),
        Line2D([], [], color="C3", lw=2, label="target" + ("s" if len(views) > 1 else "")),
    ]
    if any(v[4] is not None for v in views):
        handles.append(Line2D([], [], color="saddlebrown", lw=1, label="box"))
    frames = []
    for j, (bbr, gb) in enumerate(zip(bbs, bases, strict=True)):
        ax.cla()
        if view == "follow":  # centred on the arms in x, y; from the ground to above the drone
            top = max(gb[2, 3], *bbr[:, 0, 2, 3]) + 0.4
            h = max(1.0, 0.5 * top)
            c = np.array([*(0.5 * (bbr[:, 0, :2, 3].mean(0) + bbr[:, -1, :2, 3].mean(0))), h])
        else:
            c, h = centre, half
        ax.set_xlim(c[0] - h, c[0] + h)
        ax.set_ylim(c[1] - h, c[1] + h)
        zlo = -0.05 if view == "follow" else min(c[2] - h, -0.05)
        ax.set_zlim(zlo, zlo + 2 * h)
        ax.set_box_aspect((1, 1, 1))
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):  # few ticks: labels apart on a small frame
            axis.set_major_locator(MaxNLocator(4))
        if any(v[4] is not None for v in views):
            gx = (c[0] - h, c[0] + h)
            gy = (c[1] - h, c[1] + h)
            ground = [[(gx[0], gy[0], 0), (gx[1], gy[0], 0), (gx[1], gy[1], 0), (gx[0], gy[1], 0)]]
            ax.add_collection3d(Poly3DCollection(ground, color=(0.75, 0.78, 0.75, 0.5)))
            boxes = {(tuple(v[4].box_xy), v[4].box_size) for v in views if v[4] is not None}
            for xy, size in sorted(boxes):
                for a, b in _box_edges(xy, size):
                    ax.plot(*np.array([a, b]).T, color="saddlebrown", lw=1)
        for r in range(n_rods):
            bb = bbr[r]
            ax.plot(*bb[:, :3, 3].T, color=rod_colors[r % 4], lw=3)
            ax.plot(*np.array([gb[:3, 3], bb[0, :3, 3]]).T, color="k", lw=1)
        if system.floating:
            for a, b in _drone_arms(gb, arm):
                ax.plot(*np.array([a, b]).T, color="k", lw=2)
        for rod, mount, cam_model, tp, _ in views:
            if mount is not None:
                cam = bbr[rod, -1] @ mount
                for a, b in _frustum(cam, cam_model):
                    ax.plot(*np.array([a, b]).T, color="C2", lw=0.9)
            if tp is not None:
                poly = np.vstack([tp, tp[:1]])
                ax.plot(*poly.T, color="C3", lw=2)
        ax.legend(handles=handles, loc="upper left", fontsize=7)
        line = title
        if times is not None:
            line += f"\nt = {float(np.asarray(times)[idx[j]]):.2f} s"
            if captions is not None:
                line += f"   {captions[idx[j]]}"
        ax.set_title(line, fontsize=9)
        fig.canvas.draw()
        frames.append(np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy())
        if progress is not None:
            progress(j + 1, len(bbs))
    plt.close(fig)
    return frames


def write_animation(frames, path, fps=20) -> Path:
    """Write frames to ``.gif`` (Pillow) or ``.mp4`` (H.264, else OpenCV)."""
    path = Path(path)
    if not frames:
        raise ValueError("no frames to write")
    if path.suffix.lower() == ".gif":
        from PIL import Image

        imgs = [Image.fromarray(f) for f in frames]
        imgs[0].save(
            path, save_all=True, append_images=imgs[1:], duration=int(round(1000 / fps)), loop=0
        )
    elif path.suffix.lower() == ".mp4":
        from .video import write_video

        write_video(path, frames, fps)
    else:
        raise ValueError(f"animation path must end in .gif or .mp4, got {path}")
    return path


#: A GIF stores each frame's delay in hundredths of a second (and viewers play delays under
#: 0.02 s at 0.1 s): its frame rate is 100 / k for a whole k >= 2.
GIF_DELAY_QUANTUM = 0.01


def playback_plan(
    duration: float, n_steps: int, fps=None, max_frames=None, speed=1.0, quantum=None
):
    """``(stride, fps, actual_speed)`` for ``n_steps`` logged steps over ``duration`` s: real
    time times ``speed`` unless ``max_frames``/``fps`` forbid it (then the actual speed).
    Each frame shows ``stride`` logged periods of ``dt = duration / (n_steps - 1)``; the
    actual speed is ``stride dt fps`` (simulated seconds per second of playback). ``quantum``
    (s): the container's delay unit (:data:`GIF_DELAY_QUANTUM`): the frame delay is a whole
    number of it (at least 2), and the speed is computed with that rate."""
    duration = max(float(duration), 1e-9)
    dt = duration / max(n_steps - 1, 1)
    want_fps = 20.0 if fps is None else float(fps)
    frames = int(np.ceil(duration / speed * want_fps)) + 1
    if max_frames is not None:
        frames = min(frames, int(max_frames))
    frames = max(1, min(frames, n_steps))
    stride = max(1, int(np.ceil(n_steps / frames)))
    if fps is None:  # choose the rate that keeps the requested speed
        fps = max(1.0, min(50.0, speed / (stride * dt)))
    fps = float(fps)
    if quantum:
        fps = 1.0 / (max(2, round(1.0 / (fps * quantum))) * quantum)
    return stride, fps, stride * dt * fps


def replay_run(
    run_dir, out=None, fps=None, max_frames=200, speed=1.0, view="follow", progress=None
) -> Path:
    """Animate a ``tdacm run`` folder (``timeseries.npz``, ``summary.json``, ``scenario.toml``)."""
    from ..sim.outputs import load_run
    from ._scene import geometry

    arrays, summary, scenario = load_run(run_dir)
    run_dir = Path(run_dir)
    g = geometry(scenario)
    q = np.asarray(arrays["q"])
    t = np.asarray(arrays["t"])
    if len(t) == 0:
        raise RunDirError(f"{run_dir} holds no time steps")
    duration = float(t[-1] - t[0]) if len(t) > 1 else float(scenario.config.dt)
    out = Path(out) if out is not None else run_dir / "replay.gif"
    quantum = GIF_DELAY_QUANTUM if out.suffix.lower() == ".gif" else None
    stride, fps, actual = playback_plan(duration, len(t), fps, max_frames, speed, quantum)
    captions = None
    if "mode" in arrays:
        captions = ["recovery" if int(m) == 1 else "IBVS" for m in arrays["mode"]]
    title = f"{summary.get('scenario', scenario.name)}  (playback {actual:.2g}x real time)"
    frames = replay_frames(
        g.system, q, g.scene.target_points_world(), g.tip_mount, stride, title=title,
        times=t, scene=g.scene, view=view, camera=g.local_camera, captions=captions,
        progress=progress, arms=g.arms,
    )  # fmt: skip
    return write_animation(frames, out, fps)

"""3-D replay of a run folder (``tdacm replay RUN_DIR``): the drone, the rod's backbone, the tip
camera's optical axis and the target, animated with matplotlib and written to GIF or MP4.

GIF uses Pillow (always available with matplotlib); MP4 uses OpenCV's video writer (the
``opencv-python-headless`` wheel ships its FFmpeg backend), so nothing is downloaded.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def _drone_arms(g_b, arm):
    """Segments of a '+' quadrotor in the inertial frame."""
    ends = np.array([[arm, 0, 0], [-arm, 0, 0], [0, arm, 0], [0, -arm, 0]])
    pts = (g_b[:3, :3] @ ends.T).T + g_b[:3, 3]
    return [(pts[0], pts[1]), (pts[2], pts[3])]


def replay_frames(
    system, q_series, target_points=None, tip_mount=None, stride=1, size=(640, 520), title=""
):
    """RGB frames (list of HxWx3 uint8) of the arm moving along ``q_series``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: F401  (registers 3d)

    qs = np.asarray(q_series)[::stride]
    bbs = np.array([system.backbone(q, 21) for q in qs])
    bases = np.array([system.base_pose(q) for q in qs])
    pts = bbs[:, :, :3, 3].reshape(-1, 3)
    allp = np.vstack(
        [pts, bases[:, :3, 3]] + ([target_points] if target_points is not None else [])
    )
    lo, hi = allp.min(0), allp.max(0)
    centre, half = 0.5 * (lo + hi), 0.5 * max(np.max(hi - lo), 1.0) + 0.2
    arm = getattr(system.base, "arm_length", 0.0) if system.floating else 0.0
    fig = plt.figure(figsize=(size[0] / 100, size[1] / 100), dpi=100)
    ax = fig.add_subplot(projection="3d")
    frames = []
    for bb, gb in zip(bbs, bases, strict=True):
        ax.cla()
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        ax.plot(*bb[:, :3, 3].T, color="C1", lw=3, label="rod")
        if system.floating:
            for a, b in _drone_arms(gb, arm):
                ax.plot(*np.array([a, b]).T, color="k", lw=2)
        ax.plot(*np.array([gb[:3, 3], bb[0, :3, 3]]).T, color="k", lw=1)
        if tip_mount is not None:
            cam = bb[-1] @ tip_mount
            axis = np.array([cam[:3, 3], cam[:3, 3] + 0.4 * cam[:3, 2]])
            ax.plot(*axis.T, color="C2", lw=1, ls="--", label="C_L axis")
        if target_points is not None:
            poly = np.vstack([target_points, target_points[:1]])
            ax.plot(*poly.T, color="C3", lw=2, label="target")
        ax.set_title(title)
        fig.canvas.draw()
        img = np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
        frames.append(img)
    plt.close(fig)
    return frames


def write_animation(frames, path, fps=20) -> Path:
    """Write frames to ``.gif`` (Pillow) or ``.mp4`` (OpenCV)."""
    path = Path(path)
    if not frames:
        raise ValueError("no frames to write")
    if path.suffix.lower() == ".gif":
        from PIL import Image

        imgs = [Image.fromarray(f) for f in frames]
        imgs[0].save(path, save_all=True, append_images=imgs[1:], duration=int(1000 / fps), loop=0)
    elif path.suffix.lower() == ".mp4":
        import cv2

        h, w = frames[0].shape[:2]
        vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
        for f in frames:
            vw.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
        vw.release()
    else:
        raise ValueError(f"animation path must end in .gif or .mp4, got {path}")
    return path


def replay_run(run_dir, out=None, fps=20, max_frames=60) -> Path:
    """Animate a ``tdacm run`` folder (``timeseries.npz`` + ``summary.json``)."""
    from ..loop import build_scene
    from ..sim.scenario import load_scenario

    run_dir = Path(run_dir)
    npz = run_dir / "timeseries.npz"
    if not npz.is_file():
        raise FileNotFoundError(f"{npz} not found: is {run_dir} a `tdacm run` output folder?")
    data = np.load(npz)
    summary = json.loads((run_dir / "summary.json").read_text())
    world = build_scene(load_scenario(summary["scenario"]))
    q = data["q"]
    t = data["t"]
    stride = max(1, int(np.ceil(len(q) / max_frames)))
    target = world.scene.target_points_world()
    frames = replay_frames(
        world.robot.system, q, target, world.robot.tip_mount, stride, title=summary["scenario"]
    )
    # stamp the simulated time on every frame
    import cv2

    for f, ti in zip(frames, t[::stride], strict=False):
        cv2.putText(
            f,
            f"t = {ti:.2f} s",
            (10, 24),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.6,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    out = Path(out) if out is not None else run_dir / "replay.gif"
    return write_animation(frames, out, fps)

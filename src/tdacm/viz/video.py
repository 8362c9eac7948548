"""The run video: C_L and C_G side by side with captions, H.264 when available.

:func:`compose_frame` is called by the closed loop once per control step (when ``--video`` is
on) and returns one RGB frame; :func:`write_video` encodes the list at the end.

Encoding: H.264 (``libx264``, yuv420p, playable everywhere) through the FFmpeg binary shipped
by the ``imageio-ffmpeg`` wheel (piped raw frames; nothing is downloaded); if that binary is
missing or fails, OpenCV's ``mp4v`` writer (MPEG-4 part 2) as before.
"""

from __future__ import annotations

import logging
import subprocess
from pathlib import Path

import numpy as np

#: Side of each camera tile in the composed frame (px).
TILE = 500
_CAPTION_H = 28
_FOOTER_H = 30
MODE_NAMES = {0: "IBVS", 1: "recovery", "ibvs": "IBVS", "recovery": "recovery"}

log = logging.getLogger(__name__)


def _text(img, text, org, scale=0.55, color=(255, 255, 255), thick=1):
    import cv2

    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, color, thick, cv2.LINE_AA)


def compose_frame(
    img_local,
    img_global=None,
    *,
    t: float,
    mode=None,
    rmse: float | None = None,
    detected=None,
    desired=None,
    detected_global=None,
    local_size=None,
) -> np.ndarray:
    """One captioned video frame (RGB uint8, ``(TILE + 58, 2 TILE, 3)``).

    Parameters
    ----------
    img_local, img_global:
        The C_L image (any size, RGB) and the C_G image (or ``None``: a black tile).
    t:
        Simulated time (s).
    mode:
        ``"ibvs"``/``"recovery"`` or the logged codes 0/1 (``None``: not shown).
    rmse:
        Normalized RMSE of this step (NaN/None: "no detection").
    detected, desired:
        C_L pixels (4, 2) of the detected and the desired points (pixels of ``img_local``);
        drawn as red dots and green crosses joined by a polygon.
    detected_global:
        C_G pixels (4, 2) of the target's detected corners, drawn in yellow.
    """
    import cv2

    img_local = np.asarray(img_local)
    if img_local.ndim == 2:  # the loop renders C_L in grey
        img_local = cv2.cvtColor(
            np.ascontiguousarray(img_local, dtype=np.uint8), cv2.COLOR_GRAY2RGB
        )
    img_local = np.ascontiguousarray(img_local[:, :, :3], dtype=np.uint8)
    h0, w0 = img_local.shape[:2]
    left = cv2.resize(img_local, (TILE, TILE), interpolation=cv2.INTER_AREA)
    sx, sy = TILE / w0, TILE / h0

    def pts(p, fx, fy):
        p = np.asarray(p, float).reshape(-1, 2)
        if not np.all(np.isfinite(p)):
            return None
        return np.round(p * [fx, fy]).astype(np.int32)

    if desired is not None and (d := pts(desired, sx, sy)) is not None:
        cv2.polylines(left, [d], True, (0, 200, 0), 1, cv2.LINE_AA)
        for x, y in d:
            cv2.drawMarker(left, (int(x), int(y)), (0, 230, 0), cv2.MARKER_CROSS, 14, 2)
    if detected is not None and (d := pts(detected, sx, sy)) is not None:
        cv2.polylines(left, [d], True, (230, 40, 40), 1, cv2.LINE_AA)
        for x, y in d:
            cv2.circle(left, (int(x), int(y)), 5, (230, 40, 40), -1, cv2.LINE_AA)
    if img_global is None:
        right = np.zeros((TILE, TILE, 3), np.uint8)
        _text(right, "C_G not rendered", (150, TILE // 2), 0.6, (160, 160, 160))
    else:
        g = np.asarray(img_global)
        if g.ndim == 2:
            g = cv2.cvtColor(np.ascontiguousarray(g, dtype=np.uint8), cv2.COLOR_GRAY2RGB)
        g = np.ascontiguousarray(g[:, :, :3], dtype=np.uint8)
        gh, gw = g.shape[:2]
        right = (
            cv2.resize(g, (TILE, TILE), interpolation=cv2.INTER_AREA)
            if (gh, gw)
            != (
                TILE,
                TILE,
            )
            else g.copy()
        )
        if (
            detected_global is not None
            and (d := pts(detected_global, TILE / gw, TILE / gh)) is not None
        ):
            cv2.polylines(right, [d], True, (255, 220, 0), 2, cv2.LINE_AA)
    body = np.concatenate((left, right), axis=1)
    top = np.full((_CAPTION_H, 2 * TILE, 3), 30, np.uint8)
    _text(top, "C_L: tip camera (red: detected, green: desired)", (8, 19), 0.5)
    _text(top, "C_G: drone camera", (TILE + 8, 19), 0.5)
    foot = np.full((_FOOTER_H, 2 * TILE, 3), 30, np.uint8)
    parts = [f"t = {t:6.2f} s"]
    if mode is not None:
        parts.append(f"mode: {MODE_NAMES.get(mode, str(mode))}")
    if rmse is None or not np.isfinite(rmse):
        parts.append("normalized RMSE: - (no detection)")
    else:
        parts.append(f"normalized RMSE: {rmse:.4f}")
    _text(foot, "    ".join(parts), (8, 21), 0.6)
    return np.concatenate((top, body, foot), axis=0)


def ffmpeg_exe() -> str | None:
    """Path of the FFmpeg binary of ``imageio-ffmpeg``, or None."""
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:  # noqa: BLE001 - not installed or no binary for this platform
        return None


def write_video(path, frames, fps: float = 50) -> str:
    """Encode RGB ``frames`` to ``path`` (.mp4); returns the codec used (``"h264"`` or
    ``"mp4v"``). Frames are padded to even sizes (yuv420p needs them)."""
    path = Path(path)
    frames = list(frames)
    if not frames:
        raise ValueError("no frames to write")
    h, w = frames[0].shape[:2]
    H, W = h + h % 2, w + w % 2
    exe = ffmpeg_exe()
    if exe is not None:
        cmd = [exe, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24",
               "-s", f"{W}x{H}", "-r", f"{fps:g}", "-i", "-", "-an", "-c:v", "libx264",
               "-pix_fmt", "yuv420p", "-preset", "veryfast", "-crf", "23",
               "-movflags", "+faststart", str(path)]  # fmt: skip
        try:
            proc = subprocess.Popen(
                cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
            )
            for f in frames:
                f = np.asarray(f)[:, :, :3]
                if f.shape[:2] != (H, W):
                    pad = np.zeros((H, W, 3), np.uint8)
                    pad[: f.shape[0], : f.shape[1]] = f[:H, :W]
                    f = pad
                proc.stdin.write(np.ascontiguousarray(f, dtype=np.uint8).tobytes())
            proc.stdin.close()
            err = proc.stderr.read()
            if proc.wait() == 0 and path.is_file() and path.stat().st_size > 0:
                return "h264"
            log.warning(
                "ffmpeg failed (%s); falling back to OpenCV mp4v",
                err.decode(errors="replace").strip()[:200],
            )
        except OSError:
            pass
    import cv2

    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    for f in frames:
        vw.write(cv2.cvtColor(np.ascontiguousarray(np.asarray(f)[:, :, :3]), cv2.COLOR_RGB2BGR))
    vw.release()
    return "mp4v"


def side_by_side(img_l, img_g, pix) -> np.ndarray:
    """Uncaptioned C_L (detected points in red) | C_G, 500 x 500 each (the old frame)."""
    import cv2

    if img_l.ndim == 2:
        img_l = cv2.cvtColor(img_l, cv2.COLOR_GRAY2RGB)
    left = cv2.resize(img_l, (TILE, TILE), interpolation=cv2.INTER_AREA)
    if pix is not None:
        for p in np.asarray(pix) * TILE / img_l.shape[1]:
            cv2.circle(left, (int(p[0]), int(p[1])), 4, (255, 0, 0), -1)
    right = img_g if img_g is not None else np.zeros((TILE, TILE, 3), np.uint8)
    if right.shape[:2] != (TILE, TILE):
        right = cv2.resize(right, (TILE, TILE))
    return np.concatenate((left[:, :, :3], right[:, :, :3]), axis=1)


class CaptionedFrames:
    """The loop's per-period frame composer (``RunLog(frame_composer=...)``,
    ``tdacm.sim.assemble.build_loop(frame_composer=...)``): ``composer(readings, view, command, t)`` returns
    :func:`compose_frame` of the C_L and C_G images with the detected points, the desired
    points ``desired`` (C_L pixels, set after the loop is built: :func:`desired_pixels`), the
    time, the mode and the RMSE of ``command``."""

    def __init__(self, desired=None):
        self.desired = desired
        self.desired_arms = None  # several arms: each arm's (bind)

    def bind(self, assembly) -> None:
        """Take the desired points of an assembled loop (:func:`desired_pixels`; with several
        arms, each arm's: :func:`desired_pixels_arms`)."""
        self.desired = desired_pixels(assembly)
        self.desired_arms = desired_pixels_arms(assembly)

    def __call__(self, readings, view, command, t) -> np.ndarray:
        frame = self._one(readings, view, command, t)
        loc = readings.local
        if not (isinstance(loc, tuple) and len(loc) > 1):
            return frame
        # several arms: arm 0's C_L | C_G, then every other arm's C_L with its points
        arms = getattr(command, "arms", None) or ()
        views = getattr(view, "arms", ()) or ()
        desired = getattr(self, "desired_arms", None) or [None] * len(loc)
        # arm 0's column: its caption (the footer keeps the time, the mode and the largest
        # RMSE over the arms)
        _caption(frame[:, :TILE], "C_L arm 0 (red: detected, green: desired)")
        tiles = [frame]
        for i in range(1, len(loc)):
            m = loc[i]
            img = m.image if m.image is not None else np.zeros((TILE, TILE, 3), np.uint8)
            v = views[i] if i < len(views) else None
            one = compose_frame(
                img, None, t=float(t),
                detected=v.pixels if v is not None and v.found else None,
                desired=desired[i] if i < len(desired) else None,
            )[:, :TILE].copy()  # fmt: skip
            _caption(one, f"C_L arm {i}", _rmse_text(arms[i].rmse if i < len(arms) else None))
            tiles.append(one)
        return np.concatenate(tiles, axis=1)

    def _one(self, readings, view, command, t) -> np.ndarray:
        loc = readings.local
        img_l = loc.image if loc is not None and loc.image is not None else None
        if img_l is None:
            img_l = np.zeros((TILE, TILE, 3), np.uint8)
        g = readings.global_rendered
        img_g = g.image if g is not None else None
        det_g = g.detection.points if g is not None and g.found else None
        return compose_frame(
            img_l,
            img_g,
            t=float(t),
            mode=getattr(command, "mode", None),
            rmse=getattr(command, "rmse", None),
            detected=view.pixels if view is not None and view.found else None,
            desired=self.desired,
            detected_global=det_g,
        )


def _rmse_text(rmse) -> str:
    if rmse is None or not np.isfinite(rmse):
        return "RMSE: - (no detection)"
    return f"RMSE: {rmse:.4f}"


def _caption(tile, top: str, foot: str | None = None) -> None:
    """Overwrite the caption (and the footer) of a frame's C_L column ``tile`` (a view)."""
    tile[:_CAPTION_H] = 30
    _text(tile, top, (8, 19), 0.5)
    if foot is not None:
        tile[-_FOOTER_H:] = 30
        _text(tile, foot, (8, tile.shape[0] - 9), 0.6)


def desired_pixels_arms(assembly) -> list | None:
    """Each arm's C_L pixels (4, 2) of its target at the desired configuration, for a robot
    with several arms (``None`` for one arm)."""
    sensors = assembly.loop.sensors
    locals_ = getattr(sensors, "locals_", None)
    world = assembly.world
    if not locals_ or len(locals_) < 2:
        return None
    return [
        s.camera.project_world(world.arm(k).scene.target_points_world(), s.pose(world.q_star))
        for k, s in enumerate(locals_)
    ]


def desired_pixels(assembly) -> np.ndarray:
    """C_L pixels (4, 2) of the target at the desired configuration of an assembled loop
    (:class:`tdacm.sim.assemble.Assembly`): where the detected points converge."""
    local = assembly.loop.sensors.local
    world = assembly.world
    return local.camera.project_world(world.scene.target_points_world(), local.pose(world.q_star))

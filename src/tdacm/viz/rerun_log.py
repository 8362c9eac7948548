"""A recorded, interactive 3-D view of a run with the Rerun SDK (``.rrd``, open with
``rerun FILE.rrd``; ``pip install rerun-sdk`` ships the viewer).

Everything is on one timeline ``sim_time`` (the simulated time):

* ``world/drone`` (pose, ``Transform3D``) with its arms; ``world/rod`` (backbone line strip);
  ``world/target`` (the target's outline), ``world/box`` and ``world/ground``;
* ``world/C_L`` and ``world/C_G``: the cameras as pinholes at their poses with their images
  (re-rendered from the stored ``q`` with the planar renderer, every ``image_every`` steps,
  JPEG-compressed) and the points: detected (red, stored for C_L; detected on the re-rendered
  image for C_G) and desired (green, C_L);
* a robot with several arms (``[[robot.arms]]``) has arm ``i``'s ``world/rod{i}``,
  ``world/C_L{i}`` (its C_L sees its own marker), ``world/target{i}`` and ``world/box{i}``,
  and the plots ``plots/rmse_arms`` and ``plots/rmse_true_arms`` (each arm's RMSE);
* ``plots/...``: normalized RMSE, mode, advanced-feature error, camera twist, strains and strain
  rates, thrusts and tensions (``Scalars``).

Rerun's scalar plots and 3-D view are linked by the timeline: scrubbing the time shows the
arm, both images and the curves at that instant.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._extras import require

TIMELINE = "sim_time"


def _cols(rec, path, t, values, names=None):
    rr = require("rerun", "rerun")

    values = np.asarray(values, float)
    if values.ndim == 1:
        values = values[:, None]
    rec.send_columns(
        path,
        indexes=[rr.TimeColumn(TIMELINE, duration=t)],
        columns=rr.Scalars.columns(scalars=values),
    )
    if names is not None:
        rec.log(path, rr.SeriesLines(names=list(names)), static=True)


def record_run(
    run_dir,
    path=None,
    images: bool = True,
    image_every: int | None = None,
    image_size: int = 256,
    progress=None,
) -> Path:
    """Convert a ``tdacm run`` folder to a Rerun recording ``path`` (default
    ``RUN_DIR/run.rrd``); returns the path. ``image_every`` steps between camera images
    (default: about 100 images over the run); ``progress(done, total)`` is called per step."""
    rr = require("rerun", "rerun")

    from ..sim.outputs import load_run
    from ..vision import PlanarRenderer, TargetDetector
    from ._scene import geometry

    run_dir = Path(run_dir)
    arrays, summary, scenario = load_run(run_dir)
    path = Path(path) if path is not None else run_dir / "run.rrd"
    path.parent.mkdir(parents=True, exist_ok=True)
    g = geometry(scenario)
    GLOBAL_CAMERA = g.global_camera
    s = g.system
    t = np.asarray(arrays["t"], float)
    q = np.asarray(arrays["q"], float)
    T = len(t)
    if image_every is None:
        image_every = max(1, int(np.ceil(T / 100)))

    rec = rr.RecordingStream("tdacm", recording_id=f"tdacm-{summary.get('scenario', 'run')}")
    rec.save(str(path))
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    # the arms: one (rod, C_L, target, box) each; several arms are suffixed with their index
    arms = g.arms
    several = len(arms) > 1
    sfx = [str(a.index) if several else "" for a in arms]
    cams = [(f"C_L{x}", a.local_camera) for x, a in zip(sfx, arms, strict=True)]
    cams.append(("C_G", GLOBAL_CAMERA))
    # static scene: ground, boxes, targets
    sc = g.scene
    gs = 0.5 * getattr(sc, "ground_size", 6.0)
    rec.log(
        "world/ground",
        rr.LineStrips3D(
            [[[-gs, -gs, 0], [gs, -gs, 0], [gs, gs, 0], [-gs, gs, 0], [-gs, -gs, 0]]],
            colors=[[120, 120, 120]],
        ),
        static=True,
    )
    for x, a in zip(sfx, arms, strict=True):
        bs = a.scene.box_size
        bx, by = a.scene.box_xy
        rec.log(
            f"world/box{x}",
            rr.Boxes3D(centers=[[bx, by, bs / 2]], half_sizes=[[bs / 2] * 3],
                       colors=[[170, 130, 80]]),
            static=True,
        )  # fmt: skip
        tp = a.scene.target_points_world()
        rec.log(
            f"world/target{x}",
            rr.LineStrips3D([np.vstack([tp, tp[:1]])], colors=[[220, 40, 40]], radii=0.01),
            static=True,
        )
    for name, cam in cams:
        scale = image_size / cam.width
        rec.log(
            f"world/{name}/image",
            rr.Pinhole(
                focal_length=[cam.fx * scale, cam.fy * scale],
                principal_point=[cam.cx * scale, cam.cy * scale],
                resolution=[image_size, image_size],
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=0.25,
            ),
            static=True,
        )
    desired = [g.desired_local_pixels(a.index) * image_size / a.local_camera.width for a in arms]
    arm = getattr(s.base, "arm_length", 0.0) if s.floating else 0.0
    if s.floating:
        rec.log(
            "world/drone/arms",
            rr.LineStrips3D(
                [[[-arm, 0, 0], [arm, 0, 0]], [[0, -arm, 0], [0, arm, 0]]],
                colors=[[20, 20, 20]],
                radii=0.012,
            ),
            static=True,
        )
    # C_L of arm i renders its own scene (its marker), C_G the first arm's (as in the loop)
    renderers = [PlanarRenderer(a.scene) for a in arms] + [None] if images else []
    if images:
        renderers[-1] = renderers[0]
    det_g = TargetDetector(g.target) if images else None
    if several and "points_local_arms" in arrays:
        pl = np.asarray(arrays["points_local_arms"], float).reshape(T, len(arms), 4, 2)
    elif "points_local" in arrays and not several:
        pl = np.asarray(arrays["points_local"], float).reshape(T, 1, 4, 2)
    else:
        pl = None
    colors = [[240, 140, 20], [150, 60, 200], [40, 150, 150], [200, 60, 120]]
    try:
        for k in range(T):
            rec.set_time(TIMELINE, duration=float(t[k]))
            gb = s.base_pose(q[k])
            rec.log("world/drone", rr.Transform3D(translation=gb[:3, 3], mat3x3=gb[:3, :3]))
            for x, a in zip(sfx, arms, strict=True):
                bb = s.backbone(q[k], 21, rod=a.rod)[:, :3, 3]
                rec.log(f"world/rod{x}", rr.LineStrips3D([bb], colors=[colors[a.index % 4]],
                                                         radii=0.008))  # fmt: skip
            poses = [g.local_pose(q[k], a.index) for a in arms] + [g.global_pose(q[k])]
            for (name, _), gc in zip(cams, poses, strict=True):
                rec.log(f"world/{name}", rr.Transform3D(translation=gc[:3, 3], mat3x3=gc[:3, :3]))
            if images and k % image_every == 0:
                import cv2

                for i, ((name, cam), gc) in enumerate(zip(cams, poses, strict=True)):
                    img = renderers[i].render(cam, gc)
                    small = cv2.resize(np.ascontiguousarray(img[:, :, :3]),
                                       (image_size, image_size), interpolation=cv2.INTER_AREA)  # fmt: skip
                    rec.log(f"world/{name}/image", rr.Image(small).compress(jpeg_quality=80))
                    sc_px = image_size / cam.width
                    if i < len(arms):  # a C_L: the stored detections, the desired points
                        pts = None
                        if pl is not None:
                            p = pl[k, i]
                            if np.all(np.isfinite(p)):
                                pts = cam.denormalize(p) * sc_px
                        rec.log(f"world/{name}/image/desired",
                                rr.Points2D(desired[i], colors=[[0, 220, 0]], radii=3))  # fmt: skip
                    else:
                        d = det_g.detect(img)
                        pts = np.asarray(d.points) * sc_px if d.found else None
                    if pts is not None:
                        rec.log(f"world/{name}/image/detected",
                                rr.Points2D(pts, colors=[[230, 30, 30]], radii=3))  # fmt: skip
                    else:
                        rec.log(f"world/{name}/image/detected", rr.Clear(recursive=False))
            if progress is not None:
                progress(k + 1, T)
    finally:
        for r in renderers[:-1]:
            r.close()
    # time series as columns (one call each)
    n_base = 6 if s.floating else 0
    if "rmse" in arrays:
        _cols(rec, "plots/rmse", t, arrays["rmse"],
              ["normalized RMSE" + (" (largest over the arms)" if several else "")])  # fmt: skip
    for key, what in (("rmse_arms", "servo"), ("rmse_true_arms", "true")):
        if several and key in arrays:
            _cols(rec, f"plots/{key}", t, np.asarray(arrays[key], float).reshape(T, -1),
                  [f"arm {a.index} ({what})" for a in arms])  # fmt: skip
    if "mode" in arrays:
        _cols(rec, "plots/mode", t, arrays["mode"], ["mode (0 IBVS, 1 recovery)"])
    if "feature_error" in arrays:
        _cols(rec, "plots/feature_error", t, arrays["feature_error"],
              ["e_phi", "e_theta", "e_psi", "e_x", "e_y", "e_z"])  # fmt: skip
    if "twist" in arrays:
        _cols(rec, "plots/camera_twist", t, arrays["twist"],
              ["w_x", "w_y", "w_z", "v_x", "v_y", "v_z"])  # fmt: skip
    ns = q.shape[1] - n_base
    snames = [f"q_s{i + 1}" for i in range(ns)]
    if several:  # each arm's coordinates (Arm.strains of the system)
        snames = [f"arm{i}_q_s{j + 1}" for i, arm in enumerate(s.arms)
                  for j in range(arm.strains.stop - arm.strains.start)]  # fmt: skip
    _cols(rec, "plots/strains", t, q[:, n_base:], snames)
    if "qd" in arrays:
        _cols(rec, "plots/strain_rates", t, np.asarray(arrays["qd"])[:, n_base:],
              ["d" + x for x in snames])  # fmt: skip
    if s.floating:
        _cols(rec, "plots/drone_position", t, q[:, 3:6], ["x", "y", "z"])
    if "u" in arrays:
        u = np.asarray(arrays["u"], float)
        m = 4 if s.floating else 0
        names = [f"f{i + 1}" for i in range(m)] + [f"T{i + 1}" for i in range(u.shape[1] - m)]
        if several:
            names = names[:m] + [f"arm{i}_T{j + 1}" for i, arm in enumerate(s.arms)
                                 for j in range(arm.tendons.n)]  # fmt: skip
        _cols(rec, "plots/actuation", t, u, names)
    rec.flush()
    rec.disconnect()
    return path

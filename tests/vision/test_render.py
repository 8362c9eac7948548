"""Renderers: rendered marker corners match the analytic projection (sub-pixel), the arm is
drawn for the global camera, the renderer interface is honoured."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tdacm.vision import (
    DEFAULT_DRONE_CAMERA_MOUNT,
    GLOBAL_CAMERA,
    LOCAL_CAMERA,
    PlanarRenderer,
    PyBulletRenderer,
    Renderer,
    SceneConfig,
    TargetDetector,
    camera_pose,
)
from tdacm.vision.render import projection_matrix, view_matrix

from .vision_helpers import FakeSystem, tilted_view

# paper distances: C_L from 1.5 m (final hover at 3 m) to 3.5 m (start at 5 m);
# C_G (0.06 m under the drone) from 2.5 m to 4.5 m
# (camera, views (distance, yaw, tilt_x, tilt_y), RMS bound in px); measured RMS with the
# edge-refined detector: TinyRenderer 0.07 / 0.23 px, planar renderer 0.01 / 0.10 px
CASES = [
    (
        LOCAL_CAMERA,
        [(1.5, 20.0, 8.0, -5.0), (2.5, -120.0, -10.0, 6.0), (3.5, 75.0, 5.0, 12.0)],
        0.2,
    ),
    (
        GLOBAL_CAMERA,
        [(1.5, 35.0, 8.0, -5.0), (2.5, 160.0, -10.0, 6.0), (4.5, -60.0, 5.0, 12.0)],
        0.5,
    ),
]


def corner_errors(renderer, scene, camera, views):
    det = TargetDetector(scene.target)
    errs = []
    for dist, yaw, tx, ty in views:
        g = tilted_view(scene, dist, yaw, tx, ty)
        d = det.detect(renderer.render(camera, g))
        assert d.found, (camera.name, dist, yaw)
        errs.append(d.points - camera.project_world(scene.target_points_world(), g))
    return np.concatenate(errs)


@pytest.mark.parametrize("camera, views, bound", CASES, ids=["C_L", "C_G"])
def test_pybullet_corners_subpixel(tiny_marker, marker_scene, camera, views, bound):
    e = corner_errors(tiny_marker, marker_scene, camera, views)
    rms = np.sqrt(np.mean(np.sum(e**2, axis=1)))
    print(f"TinyRenderer {camera.name}: corner RMS {rms:.3f} px, bias {e.mean(axis=0)}")
    assert rms < bound
    assert np.all(np.abs(e.mean(axis=0)) < 0.1)  # no half-pixel convention error


@pytest.mark.parametrize("camera, views, bound", CASES, ids=["C_L", "C_G"])
def test_planar_corners_subpixel(planar_marker, marker_scene, camera, views, bound):
    e = corner_errors(planar_marker, marker_scene, camera, views)
    rms = np.sqrt(np.mean(np.sum(e**2, axis=1)))
    print(f"PlanarRenderer {camera.name}: corner RMS {rms:.3f} px, bias {e.mean(axis=0)}")
    assert rms < bound
    assert np.all(np.abs(e.mean(axis=0)) < 0.1)


def test_tiny_renderer_pixel_convention(marker_scene):
    """Area centroid of a rendered square equals the analytic one to < 0.05 px: checks the
    projection from intrinsics and the TinyRenderer row-offset compensation."""
    scene = SceneConfig(ground_rgba=(0, 0, 0, 1), box_rgba=(1, 1, 1, 1), box_size=0.3)
    with PyBulletRenderer(scene, arm=None, light=(1.0, 0.0, 0.0)) as r:
        # hide the target: only the uniformly white box top remains
        r._p.resetBasePositionAndOrientation(
            r._target, [0, 0, -50], [0, 0, 0, 1], physicsClientId=r._cid
        )
        for camera in (GLOBAL_CAMERA, LOCAL_CAMERA.scaled(0.5)):
            g = scene.viewing_pose(1.5, 13.0)
            g[:3, 3] = [0.0, 0.0, 1.8]
            img = r.render(camera, g)
            ys, xs = np.nonzero(img[:, :, 0] > 127)
            h = 0.15
            top = np.array([[-h, -h, 0.3], [h, -h, 0.3], [h, h, 0.3], [-h, h, 0.3]])
            uv = camera.project_world(top, g)
            x, y = uv[:, 0], uv[:, 1]
            x1, y1 = np.roll(x, -1), np.roll(y, -1)
            cr = x * y1 - x1 * y
            area = cr.sum() / 2
            cx = ((x + x1) * cr).sum() / (6 * area)
            cy = ((y + y1) * cr).sum() / (6 * area)
            assert xs.mean() == pytest.approx(cx, abs=0.05)
            assert ys.mean() == pytest.approx(cy, abs=0.05)
            assert len(xs) == pytest.approx(abs(area), rel=0.01)


def test_depth_output(tiny_marker, marker_scene):
    cam = GLOBAL_CAMERA
    g = marker_scene.viewing_pose(2.0)
    rgb, depth = tiny_marker.render(cam, g, depth=True)
    assert rgb.shape == (cam.height, cam.width, 3) and rgb.dtype == np.uint8
    assert depth[250, 250] == pytest.approx(2.0, abs=0.01)


def test_arm_drawn_and_moved_not_rebuilt(marker_scene):
    system = FakeSystem()
    with PyBulletRenderer(marker_scene, backend="tiny") as r:
        assert isinstance(r, Renderer) and r.draws_arm
        q = np.array([0.05, -0.03, 0.2, 0.0, 0.0, 3.0, 0.4, -0.3])
        g_b = system.base_pose(q)
        g_cg = camera_pose(g_b, DEFAULT_DRONE_CAMERA_MOUNT)
        empty = r.render(GLOBAL_CAMERA, g_cg)
        r.set_arm(g_b, system.backbone(q, 30))
        n_bodies = r._p.getNumBodies(physicsClientId=r._cid)
        img = r.render(GLOBAL_CAMERA, g_cg)
        # rod pixels (red) along the projected backbone
        pts = np.array([system.pose(q, s)[:3, 3] for s in np.linspace(0.4, 1.0, 13)])
        uv = np.round(GLOBAL_CAMERA.project_world(pts, g_cg)).astype(int)
        red = (img[:, :, 0] > 120) & (img[:, :, 1] < 90)
        hits = [red[v - 2 : v + 3, u - 2 : u + 3].any() for u, v in uv]
        assert np.mean(hits) > 0.9
        assert not ((empty[:, :, 0] > 120) & (empty[:, :, 1] < 90)).any()
        # moving the arm keeps the same bodies
        q[6] = -0.2
        r.set_arm(system.base_pose(q), system.backbone(q, 30))
        r.render(GLOBAL_CAMERA, g_cg)
        assert r._p.getNumBodies(physicsClientId=r._cid) == n_bodies
        r.set_arm(None, None)
        hidden = r.render(GLOBAL_CAMERA, g_cg)
        np.testing.assert_array_equal(hidden, empty)


def test_projection_and_view_matrices():
    m = projection_matrix(LOCAL_CAMERA, 0.0, 0.0)
    # a camera-frame point maps to the expected pixel through the OpenGL pipeline
    p = np.array([0.3, -0.2, 2.0])
    clip = m @ np.array([p[0], -p[1], -p[2], 1.0])
    ndc = clip[:3] / clip[3]
    u = (ndc[0] + 1) / 2 * LOCAL_CAMERA.width
    v = (1 - ndc[1]) / 2 * LOCAL_CAMERA.height
    np.testing.assert_allclose([u, v], LOCAL_CAMERA.project(p)[0], atol=1e-9)
    g = np.eye(4)
    g[:3, 3] = [1.0, 2.0, 3.0]
    np.testing.assert_allclose(view_matrix(g) @ [1.0, 2.0, 4.0, 1.0], [0, 0, -1, 1], atol=1e-12)


def test_renderer_validation(planar_marker):
    with pytest.raises(ValueError, match="camera"):
        planar_marker.render("C_L", np.eye(4))
    with pytest.raises(ValueError, match="camera_pose"):
        planar_marker.render(LOCAL_CAMERA, np.zeros((4, 4)))
    with pytest.raises(ValueError, match="backend"):
        PyBulletRenderer(backend="vulkan")
    with pytest.raises(ValueError, match="scene"):
        PlanarRenderer(scene=3)


def test_planar_renderer_clips_near_plane(planar_marker, marker_scene):
    """A camera just above the board, looking sideways: no mirrored ghost images."""
    g = marker_scene.viewing_pose(0.6)
    from scipy.spatial.transform import Rotation

    g[:3, :3] = g[:3, :3] @ Rotation.from_euler("x", 80, degrees=True).as_matrix()
    img = planar_marker.render(LOCAL_CAMERA, g)
    assert img.shape == (1024, 1024, 3)
    g2 = marker_scene.viewing_pose(0.6)
    g2[:3, 3] += [0.0, 0.0, -0.9]  # below the box top: the board is seen from behind
    planar_marker.render(LOCAL_CAMERA, g2)


def test_egl_backend_in_subprocess():
    """The EGL plugin (if it loads here) renders the marker with the same accuracy. Run in
    a subprocess: a failing GL stack must not take the test session down."""
    code = textwrap.dedent(
        """
        import numpy as np
        from tdacm.vision import (GLOBAL_CAMERA, LOCAL_CAMERA, PyBulletRenderer, SceneConfig,
                                  TargetDetector)
        sc = SceneConfig()
        try:
            r = PyBulletRenderer(sc, backend="egl")
        except RuntimeError:
            print("NOEGL"); raise SystemExit(0)
        det = TargetDetector(sc.target)
        worst = 0.0
        for cam, dist in ((GLOBAL_CAMERA, 2.5), (GLOBAL_CAMERA, 4.5), (LOCAL_CAMERA, 1.5)):
            g = sc.viewing_pose(dist, 33.0)
            d = det.detect(r.render(cam, g))
            assert d.found, (cam.name, dist)
            e = d.points - cam.project_world(sc.target_points_world(), g)
            worst = max(worst, float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))))
        r.close()
        print("RMS", worst)
        """
    )
    import os

    import tdacm.vision

    src = os.path.dirname(os.path.dirname(os.path.dirname(tdacm.vision.__file__)))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([src, os.environ.get("PYTHONPATH", "")]))
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env
    )
    if "NOEGL" in out.stdout or out.returncode < 0:
        pytest.skip(f"EGL renderer unavailable here (rc={out.returncode})")
    assert out.returncode == 0, out.stderr[-2000:]
    rms = float(out.stdout.split("RMS")[-1])
    assert rms < 0.8


def test_pybullet_prints_no_banner_unless_debug_logging_is_on():
    """pybullet's C-level output (build time, the EGL plugin's GL banner) is dropped: stdout
    and stderr stay empty; with the ``tdacm`` logger at DEBUG (``tdacm -v``) it goes to
    stderr."""
    code = (
        "import logging, sys\n"
        "if sys.argv[1] == 'debug': logging.getLogger('tdacm').setLevel(logging.DEBUG)\n"
        "from tdacm.vision.render import PyBulletRenderer\n"
        "r = PyBulletRenderer(backend='auto'); print(r.backend, file=sys.stderr); r.close()\n"
    )
    quiet = subprocess.run([sys.executable, "-c", code, "quiet"], capture_output=True, text=True)
    assert quiet.returncode == 0, quiet.stderr
    backend = quiet.stderr.strip()
    assert quiet.stdout == "" and backend in ("egl", "tiny"), quiet.stderr
    debug = subprocess.run([sys.executable, "-c", code, "debug"], capture_output=True, text=True)
    assert debug.stdout == ""
    if backend == "egl":
        assert "GL_VERSION" in debug.stderr

"""The geometry of a scenario without the closed loop: system, scene, camera mounts.

The figures, the replay and the Rerun recording re-render a stored run from its
``scenario.toml``; they need only these pieces (not the runner), so they keep working when the
loop is restructured.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..sim.assemble import build_world
from ..sim.scenario import ScenarioError, load_scenario
from ..vision.mounts import tip_camera_pose


@dataclass
class Geometry:
    scenario: object
    system: object
    scene: object
    target: object
    tip_mount: np.ndarray
    drone_mount: np.ndarray
    q_star: np.ndarray
    local_camera: object
    global_camera: object

    def local_pose(self, q):
        return tip_camera_pose(self.system, q, self.tip_mount)

    def global_pose(self, q):
        return self.system.base_pose(q) @ self.drone_mount

    def desired_local_pixels(self) -> np.ndarray:
        """The target's four corners in C_L at the desired configuration (4, 2) px: where the
        detected points go when the servo converges (the reference view)."""
        return self.local_camera.project_world(
            self.scene.target_points_world(), self.local_pose(self.q_star)
        )


def geometry(scenario) -> Geometry:
    """The :class:`Geometry` of a :class:`~tdacm.sim.Scenario` (its ``[robot]`` section,
    through :func:`tdacm.sim.assemble.build_world`)."""
    w = build_world(scenario)
    r = w.robot
    return Geometry(
        scenario, r.system, w.scene, w.target, r.tip_mount, r.drone_mount, w.q_star,
        r.local_camera, r.global_camera,
    )  # fmt: skip


class RunDirError(ValueError):
    """A folder that is not a complete ``tdacm run`` output."""


def load_run(run_dir):
    """``(arrays, summary, scenario)`` of a run folder; the scenario from its
    ``scenario.toml`` (self-contained folder), else by the name in ``summary.json``."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise RunDirError(f"RUN_DIR {run_dir} does not exist or is not a folder")
    npz = run_dir / "timeseries.npz"
    if not npz.is_file():
        raise RunDirError(f"{npz} not found: is {run_dir} a `tdacm run` output folder?")
    with np.load(npz) as data:
        arrays = {k: data[k] for k in data.files}
    sj = run_dir / "summary.json"
    summary = json.loads(sj.read_text()) if sj.is_file() else {}
    toml = run_dir / "scenario.toml"
    try:
        if toml.is_file():
            scenario = load_scenario(toml)
        elif "scenario" in summary:
            scenario = load_scenario(summary["scenario"])
        else:
            raise RunDirError(f"{run_dir} has neither scenario.toml nor summary.json")
    except ScenarioError as exc:
        raise RunDirError(f"{run_dir}: cannot load its scenario: {exc}") from None
    return arrays, summary, scenario

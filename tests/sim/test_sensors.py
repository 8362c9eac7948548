"""Camera imperfections used by campaigns (:class:`tdacm.loop.sensors.SensorModel` applied by
:class:`~tdacm.loop.sensors.CameraSensor`): noise, dropouts, latency, intrinsics errors."""

import numpy as np
import pytest

from tdacm.loop.data import PlantState
from tdacm.loop.sensors import CameraSensor, SensorModel, perturbed_camera
from tdacm.sim import ScenarioError, load_scenario
from tdacm.sim.runner import Simulation
from tdacm.system.paper import paper_system
from tdacm.vision import LOCAL_CAMERA, Detection

POINTS = np.array([[100.0, 100.0], [100.0, 200.0], [200.0, 200.0], [200.0, 100.0]])


class FixedFrontEnd:
    """Detects the same four points at every pose (no renderer, no detector)."""

    camera = LOCAL_CAMERA

    def detect_at(self, pose, system, q, need_image):
        return Detection(True, POINTS.copy(), (65,), {65: POINTS.copy()}), None

    def reset(self):
        pass


#: the carrier: the paper's robot held at rest (the front end above ignores the pose)
SYSTEM = paper_system()
REST = np.zeros(SYSTEM.n)


def sensor(model: SensorModel, seed=0) -> CameraSensor:
    return CameraSensor(SYSTEM, "tip", np.eye(4), FixedFrontEnd(), model,
                        np.random.default_rng(seed))  # fmt: skip


def test_noise_and_dropout_statistics():
    cam = sensor(SensorModel(pixel_noise=1.0, dropout=0.2))
    results = [cam.measure(PlantState(0.01 * k, REST, REST)).detection for k in range(4000)]
    found = [r for r in results if r.found]
    assert abs(1 - len(found) / 4000 - 0.2) < 0.03  # binomial std 0.006
    err = np.array([r.points - POINTS for r in found])
    assert abs(err.std() - 1.0) < 0.03 and abs(err.mean()) < 0.03


def test_latency_and_intrinsics():
    late = sensor(SensorModel(latency_steps=2))
    seen = [late.measure(PlantState(float(k), REST, REST)).t_capture for k in range(5)]
    assert seen == [0.0, 0.0, 0.0, 1.0, 2.0]  # the first frame until the FIFO is full
    cam = perturbed_camera(LOCAL_CAMERA, 0.01, np.random.default_rng(1))
    assert cam.fx != LOCAL_CAMERA.fx and abs(cam.fx / LOCAL_CAMERA.fx - 1) < 0.05
    assert perturbed_camera(LOCAL_CAMERA, 0.0, np.random.default_rng(1)) is LOCAL_CAMERA


def test_sensor_values_are_validated():
    sc = load_scenario("paper-in-fov")
    with pytest.raises(ScenarioError, match="sensors.dropout"):
        sc.with_overrides({"sensors": {"dropout": 1.5}}, "test")
    with pytest.raises(ScenarioError, match="latency_steps"):
        sc.with_overrides({"sensors": {"latency_steps": -1}}, "test")


def test_short_run_with_imperfect_sensors_is_reproducible():
    sc = load_scenario("paper-in-fov").with_overrides(
        {
            "sensors": {"pixel_noise": 1.0, "dropout": 0.3, "latency_steps": 1},
            "cameras": {"global_every": 0},
        },
        "test",
    )
    _, a = Simulation(sc, duration=0.3, seed=5).run(None)
    _, b = Simulation(sc, duration=0.3, seed=5).run(None)
    assert a["local_detection_rate"] < 0.95
    assert (
        a["final_rmse"] == b["final_rmse"]
        and a["local_detection_rate"] == b["local_detection_rate"]
    )

"""MCAP export of a run with two arms (``dual-in-fov``, 0.1 s): each arm's camera frame on its
rod's tip, its target, tip pose, camera info and re-rendered C_L images; the offline replay
refuses a robot with several arms naming the key."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from tdacm.recording import RecordingError, export_run, load_run_folder, replay
from tdacm.recording.export import arm_topics
from tdacm.sim import Simulation, load_scenario

FAST = '[cameras]\nglobal_every = 0\nglobal_renderer = "planar"\n'


@pytest.fixture(scope="module")
def dual(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dual")
    (tmp / "fast.toml").write_text(FAST)
    Simulation(load_scenario("dual-in-fov", tmp / "fast.toml"), duration=0.1).run(tmp / "run")
    path = export_run(tmp / "run", tmp / "run.mcap", render_every=3)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        msgs = [(c.topic, m.log_time, d) for _, c, m, d in reader.iter_decoded_messages()]
    return load_run_folder(tmp / "run"), msgs


def _by_topic(msgs):
    out = {}
    for topic, ns, msg in msgs:
        out.setdefault(topic, []).append((ns, msg))
    return out


def test_both_arms_topics_are_written(dual):
    _, msgs = dual
    topics = set(_by_topic(msgs))
    assert set(arm_topics(2)) <= topics
    assert {"/tdacm/C_L/image_raw", "/tdacm/arm1/C_L/image_raw"} <= topics


def test_each_arms_tip_pose_and_camera_frame(dual):
    run, msgs = dual
    s = run.robot.system
    by = _by_topic(msgs)
    q = np.asarray(run.arrays["q"], float)
    for k, (_, msg) in enumerate(by["/tdacm/arm1/tip/pose"]):
        p = msg.pose.position
        assert np.allclose([p.x, p.y, p.z], s.tip_pose(q[k], 1)[:3, 3], atol=1e-12, rtol=0)
    static = by["/tf_static"][0][1].transforms
    pairs = {(tf.header.frame_id, tf.child_frame_id): tf for tf in static}
    assert ("tip", "C_L_optical") in pairs and ("rod2_tip", "arm1_C_L_optical") in pairs
    assert ("world", "arm1_target") in pairs
    tr = pairs[("world", "arm1_target")].transform.translation
    target1 = run.scenes[1].target_pose[:3, 3]
    assert np.allclose([tr.x, tr.y, tr.z], target1)
    assert abs(target1[0] - run.scene.target_pose[0, 3]) > 0.3  # each arm's own marker
    img = by["/tdacm/arm1/C_L/image_raw"][0][1]
    assert (
        img.header.frame_id == "arm1_C_L_optical"
        and img.width == run.robot.arms[1].local_camera.width
    )
    rm = [m.data for _, m in by["/tdacm/arm1/servo/rmse"]]
    assert np.allclose(rm, np.asarray(run.arrays["rmse_arms"])[:, 1], equal_nan=True)


def test_the_offline_replay_refuses_several_arms():
    with pytest.raises(RecordingError, match=r"^robot\.arms: "):
        replay({}, "dual-in-fov")

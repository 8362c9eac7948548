"""MCAP export of a run folder and import through a topic map (docs/recordings.md)."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from tdacm.cli import main
from tdacm.recording import (
    DEFAULT_TOPIC_MAP,
    DEFAULT_TOPICS,
    ExportError,
    export_run,
    load_run_folder,
    load_signals,
    pose_matrices,
    read_mcap,
)
from tdacm.sim import Simulation, load_scenario
from tdacm.sim.outputs import write_run

FAST = '[cameras]\nlocal_renderer = "analytic"\nglobal_renderer = "planar"\n'


def _decoded(path):
    """Every message of ``path`` decoded by the ROS 2 decoder: [(topic, type, log_time, msg)]."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        out = []
        for schema, channel, message, msg in reader.iter_decoded_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            out.append((channel.topic, schema.name, message.log_time, msg))
    return out


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A real 0.5 s run of ground-test-a (drone held): the run folder's data, no figures."""
    tmp = tmp_path_factory.mktemp("run")
    (tmp / "fast.toml").write_text(FAST)
    sim = Simulation(load_scenario("ground-test-a", tmp / "fast.toml"), duration=0.5)
    out = tmp / "run"
    sim.run(out)
    return out


@pytest.fixture(scope="module")
def synthetic_frames():
    """Two C_L frames (a gradient and its negative) at 0.1 s and 0.3 s."""
    img = np.zeros((6, 8, 3), np.uint8)
    img[..., 0] = np.arange(8)[None, :] * 30
    img[..., 1] = np.arange(6)[:, None] * 40
    img[..., 2] = 7
    return np.array([0.1, 0.3]), np.stack([img, 255 - img])


@pytest.fixture(scope="module")
def exported(run_dir, synthetic_frames, tmp_path_factory):
    path = tmp_path_factory.mktemp("mcap") / "run.mcap"
    return export_run(run_dir, path, images={"C_L": synthetic_frames})


@pytest.fixture(scope="module")
def run(run_dir):
    return load_run_folder(run_dir)


def test_every_message_decodes_with_the_ros2_decoder(exported, run):
    msgs = _decoded(exported)
    T = len(run.arrays["t"])
    count = {}
    for topic, kind, _, _ in msgs:
        assert DEFAULT_TOPICS[topic] == kind
        count[topic] = count.get(topic, 0) + 1
    per_step = [tp for tp in DEFAULT_TOPICS if tp not in (
        "/tf_static", "/tdacm/target/pose", "/tdacm/goal/camera_pose", "/tdacm/rotors",
        "/tdacm/C_L/image_raw", "/tdacm/C_G/image_raw")]  # fmt: skip
    assert all(count[tp] == T for tp in per_step), count
    assert count["/tf_static"] == count["/tdacm/target/pose"] == 1
    assert count["/tdacm/C_L/image_raw"] == 2  # the synthetic frames
    assert "/tdacm/rotors" not in count and "/tdacm/C_G/image_raw" not in count  # fixed base
    # log times are non-decreasing (an MCAP player replays in this order) and are the stamps
    times = [lt for *_, lt, _ in [(m[0], m[1], m[2], m[3]) for m in msgs]]
    assert times == sorted(times)
    for topic, _, lt, msg in msgs:
        if topic not in ("/tf", "/tf_static", "/tdacm/servo/features", "/tdacm/servo/rmse",
                         "/tdacm/servo/feature_error", "/tdacm/servo/points_local"):  # fmt: skip
            assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == lt
    # /tf_static is latched for `ros2 bag play`
    with open(exported, "rb") as f:
        chans = make_reader(f).get_summary().channels.values()
    qos = {c.topic: c.metadata.get("offered_qos_profiles", "") for c in chans}
    assert "durability: 1" in qos["/tf_static"]


def test_round_trip_gives_the_stored_signals(exported, run):
    a, s = run.arrays, run.robot.system
    # the features' image marker draws /tdacm/servo/points_local in pixels: imported from there
    assert set(DEFAULT_TOPIC_MAP) == set(DEFAULT_TOPICS) - {"/tf", "/tf_static",
                                                            "/tdacm/C_L/features"}  # fmt: skip
    sig = read_mcap(exported)
    t = a["t"]
    for name in ("strains", "strain_rates", "tensions", "features", "rmse", "tip_pose"):
        assert np.abs(sig[name].t - t).max() <= 0.5e-9  # stamps are integer nanoseconds
    # numbers written as float64: back bit for bit (NaN where the points were not detected)
    np.testing.assert_array_equal(sig["strains"].values, a["q"])
    np.testing.assert_array_equal(sig["strain_rates"].values, a["qd"])
    np.testing.assert_array_equal(sig["strain_forces"].values, a["tau"])
    np.testing.assert_array_equal(sig["tensions"].values, a["u"])  # fixed base: u = tensions
    for key in ("features", "feature_error", "points_local", "rmse"):
        np.testing.assert_array_equal(sig[key].values, a[key])
    assert sig["strains"].names == ("q_s1", "q_s2")
    assert sig["tensions"].names == ("T1", "T2", "T3", "T4")
    assert sig["features"].names == ("p_phi", "p_theta", "p_psi", "p_x", "p_y", "p_z")
    assert sig["points_local"].names == ("x", "y")  # (T, 4, 2) as stored
    lengths = np.array([s.tendon_lengths(q) for q in a["q"]])
    np.testing.assert_array_equal(sig["tendon_lengths"].values, lengths)
    # poses: through a unit quaternion, to round-off
    g_tip = pose_matrices(sig["tip_pose"])
    g_ref = np.array([s.tip_pose(q) for q in a["q"]])
    assert np.abs(g_tip - g_ref).max() < 1e-14
    assert np.abs(pose_matrices(sig["target_pose"])[0] - run.scene.target_pose).max() < 1e-14
    # camera info from the robot's intrinsics
    cam = run.robot.local_camera
    assert sig["C_L_info"].values[0].tolist() == [cam.fx, cam.fy, cam.cx, cam.cy,
                                                  cam.width, cam.height]  # fmt: skip


def test_synthetic_frames_come_back_as_images(exported, synthetic_frames):
    t, frames = synthetic_frames
    img = read_mcap(exported)["C_L_image"]
    assert img.values.dtype == np.uint8 and img.names == ("rgb8",)
    np.testing.assert_array_equal(img.values, frames)
    assert np.abs(img.t - t).max() <= 0.5e-9
    info = [m for m in _decoded(exported) if m[0] == "/tdacm/C_L/image_raw"][0][3]
    assert info.header.frame_id == "C_L_optical" and info.step == 8 * 3


def _tf_tree(msgs, k):
    """parent, pose-in-parent of every frame at the k-th /tf message (plus /tf_static)."""
    tree = {}
    tfs = [m for m in msgs if m[0] == "/tf"]
    for m in [*[m for m in msgs if m[0] == "/tf_static"], tfs[k]]:
        for tr in m[3].transforms:
            r, p = tr.transform.rotation, tr.transform.translation
            g = np.eye(4)
            g[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
            g[:3, 3] = [p.x, p.y, p.z]
            tree[tr.child_frame_id] = (tr.header.frame_id, g)
    return tree


def _in_world(tree, frame):
    g = np.eye(4)
    while frame != "world":
        parent, h = tree[frame]
        g = h @ g
        frame = parent
    return g


def _hat(xi):
    """4x4 of a twist ``[w; v]``."""
    w, v = xi[:3], xi[3:]
    return np.array([[0, -w[2], w[1], v[0]], [w[2], 0, -w[0], v[1]],
                     [-w[1], w[0], 0, v[2]], [0, 0, 0, 0]])  # fmt: skip


def _check_tf_chain(path, run, n_sections=10):
    msgs = _decoded(path)
    s, r = run.robot.system, run.robot
    q_all = np.asarray(run.arrays["q"], float)
    L = s.arms[0].length
    for k in (0, len(q_all) // 2, len(q_all) - 1):
        q, tree = q_all[k], _tf_tree(msgs, k)
        # the composed chain world -> base_link -> rod_base -> rod_1 ... -> tip is the model's
        assert np.abs(_in_world(tree, "tip") - s.tip_pose(q)).max() < 1e-12
        assert np.abs(_in_world(tree, "rod_base") - s.pose(q, 0.0)).max() < 1e-12
        assert np.abs(_in_world(tree, "base_link") - s.base_pose(q)).max() < 1e-12
        for j in (1, 5, 9):
            assert np.abs(_in_world(tree, f"rod_{j}") - s.pose(q, j * L / 10)).max() < 1e-12
        g_cl = _in_world(tree, "C_L_optical")
        assert np.abs(g_cl - s.tip_pose(q) @ r.tip_mount).max() < 1e-12
        g_cg = _in_world(tree, "C_G_optical")
        assert np.abs(g_cg - s.base_pose(q) @ r.drone_mount).max() < 1e-12
        # the paper's basis (constant curvature): every section-to-section transform is
        # exp(h xi^) with the rod's strain twist xi, eq. (5)
        step = expm(L / n_sections * _hat(s.strain(q, 0.5 * L)))
        for j in range(2, n_sections):
            assert np.abs(tree[f"rod_{j}"][1] - step).max() < 1e-12
        assert tree["rod_2"][0] == "rod_1" and tree["tip"][0] == f"rod_{n_sections - 1}"


def test_tf_chain_composes_to_the_model_poses(exported, run):
    _check_tf_chain(exported, run)


def test_floating_base_run_folder_exports_the_drone_and_rotors(tmp_path):
    """A run folder written from a synthetic log of the flying paper scenario: /tf moves the
    drone, /tdacm/rotors carries the thrusts, tensions are u's last four columns."""
    sc = load_scenario("paper-in-fov")
    rng = np.random.default_rng(3)
    T = 5
    q0 = np.asarray(sc["initial"]["q"], float)
    q = q0 + rng.normal(0, [0.05, 0.05, 0.1, 0.2, 0.2, 0.2, 0.3, 0.3], (T, 8))
    arrays = {"t": 0.02 * np.arange(T), "q": q, "qd": rng.normal(size=(T, 8)),
              "u": rng.uniform(0, 5, (T, 8)), "tau": rng.normal(size=(T, 8)),
              "rmse": rng.uniform(size=T), "points_local": rng.normal(size=(T, 4, 2))}  # fmt: skip
    arrays["points_local"][2] = np.nan  # target not detected at that step
    write_run(tmp_path / "run", arrays, {}, np.zeros((4, 2)), None, scenario=sc)
    path = export_run(tmp_path / "run", tmp_path / "f.mcap")
    run = load_run_folder(tmp_path / "run")
    _check_tf_chain(path, run)
    sig = read_mcap(path)
    np.testing.assert_array_equal(sig["thrusts"].values, arrays["u"][:, :4])
    np.testing.assert_array_equal(sig["tensions"].values, arrays["u"][:, 4:])
    np.testing.assert_array_equal(sig["strains"].values, q[:, 6:])
    assert sig["thrusts"].names == ("f1", "f2", "f3", "f4")
    np.testing.assert_array_equal(sig["points_local"].values, arrays["points_local"])  # NaN too
    assert np.isnan(sig["points_local"].values[2]).all()
    g = pose_matrices(sig["drone_pose"])
    assert np.abs(g - np.array([run.robot.system.base_pose(x) for x in q])).max() < 1e-14


# ------------------------------------------------------------------ a lab's own recording
# ROS 2 definitions as a lab's bag stores them (with comments), written here independently of
# tdacm.live.msgdefs
_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "# Standard metadata\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
SEP = "=" * 80 + "\n"
POSE_DEF = (
    "std_msgs/Header header\ngeometry_msgs/Pose pose\n" + SEP + "MSG: std_msgs/Header\n"
    + _HEADER + SEP + "MSG: builtin_interfaces/Time\n" + _TIME + SEP
    + "MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation\n" + SEP
    + "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n" + SEP
    + "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
)  # fmt: skip
JOINT_DEF = (
    "std_msgs/Header header\nstring[] name\nfloat64[] position  # rad or m\n"
    "float64[] velocity\nfloat64[] effort\n" + SEP + "MSG: std_msgs/Header\n" + _HEADER
    + SEP + "MSG: builtin_interfaces/Time\n" + _TIME
)  # fmt: skip
ARRAY_DEF = (
    "MultiArrayLayout layout\nfloat64[] data\n" + SEP + "MSG: std_msgs/MultiArrayLayout\n"
    "MultiArrayDimension[] dim\nuint32 data_offset\n" + SEP
    + "MSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride\n"
)  # fmt: skip

LAB_MAP = """
[topics]
"/mocap/uav" = "tip_pose"
"/arm/joints" = { position = "strains", velocity = "strain_rates" }
"/arm/tendon_tension" = "tensions"
"/vs/err" = "feature_error"
"""


def _write_lab_recording(path, sig, t0_ns):
    """The signals under a lab's topic names, stamped from ``t0_ns`` (epoch time)."""
    with open(path, "wb") as f, Writer(f) as w:
        pose = w.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_DEF)
        joints = w.register_msgdef("sensor_msgs/msg/JointState", JOINT_DEF)
        arr = w.register_msgdef("std_msgs/msg/Float64MultiArray", ARRAY_DEF)
        for k, t in enumerate(sig["strains"].t):
            ns = t0_ns + round(t * 1e9)
            stamp = {"sec": ns // 10**9, "nanosec": ns % 10**9}
            x, y, z, qx, qy, qz, qw = sig["tip_pose"].values[k]
            w.write_message("/mocap/uav", pose, {
                "header": {"stamp": stamp, "frame_id": "vicon_world"},
                "pose": {"position": {"x": x, "y": y, "z": z},
                         "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}}, ns, ns)  # fmt: skip
            w.write_message("/arm/joints", joints, {
                "header": {"stamp": stamp}, "name": ["k_y", "k_z"],
                "position": sig["strains"].values[k].tolist(),
                "velocity": sig["strain_rates"].values[k].tolist()}, ns, ns)  # fmt: skip
            w.write_message("/arm/tendon_tension", joints, {
                "header": {"stamp": stamp}, "name": ["a", "b", "c", "d"],
                "effort": sig["tensions"].values[k].tolist()}, ns, ns)  # fmt: skip
            # no header: the time is the log time; no labels: the names are generated
            w.write_message("/vs/err", arr, {"layout": {"dim": [], "data_offset": 0},
                            "data": sig["feature_error"].values[k].tolist()}, ns, ns)  # fmt: skip


def test_a_lab_recording_with_other_topics_imports_through_a_topic_map(exported, tmp_path):
    ref = read_mcap(exported)
    lab = tmp_path / "lab.mcap"
    t0_ns = 1_764_633_600 * 10**9  # a wall-clock start, as a lab's recorder stamps
    _write_lab_recording(lab, ref, t0_ns)
    (tmp_path / "map.toml").write_text(LAB_MAP)
    got = read_mcap(lab, tmp_path / "map.toml", t0="first")
    assert set(got) == {"tip_pose", "strains", "strain_rates", "tensions", "feature_error"}
    for name, s in got.items():
        np.testing.assert_array_equal(s.values, ref[name].values)
        assert np.abs(s.t - ref[name].t).max() < 1e-9
    assert got["strains"].names == ("k_y", "k_z") and got["tip_pose"].topic == "/mocap/uav"
    assert got["feature_error"].names[0] == "feature_error[0]"
    # the CLI writes the same signals
    assert main(["import", str(lab), "--topic-map", str(tmp_path / "map.toml"),
                 "--out", str(tmp_path / "sig"), "--relative"]) == 0  # fmt: skip
    back = load_signals(tmp_path / "sig")
    for name, s in got.items():
        np.testing.assert_array_equal(back[name].values, s.values)
        np.testing.assert_array_equal(back[name].t, s.t)
        assert back[name].names == s.names and back[name].msg_type == s.msg_type


def test_tf_frames_import_through_a_topic_map(exported, run):
    sig = read_mcap(exported, {"/tf": {"tip": "tip_in_rod9", "base_link": "drone"}})
    g = pose_matrices(sig["tip_in_rod9"])
    s, q = run.robot.system, run.arrays["q"]
    L = s.arms[0].length
    ref = np.array([np.linalg.solve(s.pose(x, 0.9 * L), s.tip_pose(x)) for x in q])
    assert np.abs(g - ref).max() < 1e-12 and len(sig["drone"]) == len(q)


def test_planar_renderer_images(run_dir, tmp_path, run):
    path = export_run(run_dir, tmp_path / "img.mcap", topics=["/tdacm/C_L/image_raw"],
                      render_every=20)  # fmt: skip
    img = read_mcap(path)["C_L_image"]
    cam = run.robot.local_camera
    assert img.values.shape == (2, cam.height, cam.width, 3)  # steps 0 and 20 of 26
    np.testing.assert_allclose(img.t, run.arrays["t"][[0, 20]], atol=1e-9)
    assert img.values.std() > 10  # the target and the box are drawn


def test_cli_export_and_import(run_dir, tmp_path, capsys):
    f = tmp_path / "cli.mcap"
    assert main(["export", str(run_dir), "--mcap", str(f), "--sections", "4"]) == 0
    msgs = _decoded(f)
    frames = {tr.child_frame_id for m in msgs if m[0] == "/tf" for tr in m[3].transforms}
    assert frames == {"base_link", "rod_1", "rod_2", "rod_3", "tip"}
    assert main(["import", str(f), "--out", str(tmp_path / "sig")]) == 0
    assert "strains" in capsys.readouterr().out
    np.testing.assert_array_equal(load_signals(tmp_path / "sig")["strains"].values,
                                  np.load(run_dir / "timeseries.npz")["q"])  # fmt: skip


@pytest.mark.parametrize(
    "argv, flag",
    [
        (["export", "RUN", "--mcap", "x.bag"], "--mcap"),
        (["export", "missing-folder", "--mcap", "x.mcap"], "RUN_DIR"),
        (["import", "missing.mcap", "--out", "o"], "FILE"),
        (["import", "MCAP", "--topic-map", "bad.toml", "--out", "o"], "--topic-map"),
        (["import", "MCAP", "--topic-map", "absent.toml", "--out", "o"], "--topic-map"),
        (["import", "MCAP", "--topic-map", "nomatch.toml", "--out", "o"], "--topic-map"),
        (["import", "MCAP", "--out", "afile"], "--out"),
    ],
)
def test_cli_errors_name_the_flag(argv, flag, exported, run_dir, tmp_path, capsys):
    (tmp_path / "bad.toml").write_text('[topics]\n"/a" = 3\n')
    (tmp_path / "nomatch.toml").write_text('[topics]\n"/not/recorded" = "x"\n')
    (tmp_path / "afile").write_text("")
    subs = {"RUN": str(run_dir), "MCAP": str(exported)}
    argv = [subs.get(a, str(tmp_path / a) if a.endswith((".toml", ".bag")) or a in (
        "o", "afile") else a) for a in argv]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and flag in err[0], err


def test_messages_are_the_official_ros2_layout(exported):
    """Every message re-encoded by rosbags from the ROS 2 Humble interface definitions (its
    own type store, not the schemas in the file) gives the same CDR bytes."""
    typesys = pytest.importorskip("rosbags.typesys")
    ts = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)
    seen = set()
    with open(exported, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            msg = ts.deserialize_cdr(message.data, schema.name)
            assert ts.serialize_cdr(msg, schema.name).tobytes() == message.data, channel.topic
            seen.add(schema.name)
    assert seen == set(DEFAULT_TOPICS.values())


def test_embedded_definitions_name_the_official_fields():
    """Field names and types of every embedded definition are those of ROS 2 Humble."""
    from tdacm.live.msgdefs import DEFINITIONS, schema_text

    typesys = pytest.importorskip("rosbags.typesys")
    ts = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)

    def fields(text):  # the first message's (type without package, name); no constants
        out = []
        for line in text.split("=" * 80)[0].splitlines():
            if line.strip() and not line.startswith("#"):
                ftype, name = line.split()[:2]
                if "=" not in name:  # a constant (int32 CIRCLE=0): not a field, no CDR bytes
                    out.append((ftype.rpartition("/")[2], name))
        return out

    for name in DEFINITIONS:
        assert fields(DEFINITIONS[name]) == fields(ts.generate_msgdef(name, ros_version=2)[0])
        # every type used is defined once in the schema text
        text = schema_text(name)
        used = {ln.split()[0].split("[")[0].rpartition("/")[2] for ln in text.splitlines()
                if ln.strip() and not ln.startswith(("=", "MSG:"))}  # fmt: skip
        defined = {ln.split("/")[-1] for ln in text.splitlines() if ln.startswith("MSG: ")}
        prim = {"float64", "float32", "int32", "uint32", "uint8", "string", "bool"}
        assert used - prim <= defined, name
        assert len(defined) == text.count("MSG: ")


def test_other_message_types_import(tmp_path):
    """Odometry, PoseWithCovarianceStamped, PointStamped, Vector3Stamped, Float32 and a 2-D
    Float32MultiArray, with the schemas rosbags generates from the ROS 2 definitions."""
    typesys = pytest.importorskip("rosbags.typesys")
    ts = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)
    path = tmp_path / "other.mcap"
    stamp = lambda k: {"sec": 100 + k, "nanosec": 5}  # noqa: E731
    pose = lambda k: {"position": {"x": k, "y": 2.0, "z": 3.0},  # noqa: E731
                      "orientation": {"x": 0.0, "y": 0.0, "z": 0.6, "w": 0.8}}  # fmt: skip
    msgs = {
        "/odom": ("nav_msgs/msg/Odometry",
                  lambda k: {"header": {"stamp": stamp(k)}, "pose": {"pose": pose(k)}}),
        "/pwc": ("geometry_msgs/msg/PoseWithCovarianceStamped",
                 lambda k: {"header": {"stamp": stamp(k)}, "pose": {"pose": pose(k)}}),
        "/pt": ("geometry_msgs/msg/PointStamped",
                lambda k: {"header": {"stamp": stamp(k)}, "point": {"x": k, "y": -1, "z": 0}}),
        "/vec": ("geometry_msgs/msg/Vector3Stamped",
                 lambda k: {"header": {"stamp": stamp(k)}, "vector": {"x": 0, "y": k, "z": 1}}),
        "/f": ("std_msgs/msg/Float32", lambda k: {"data": 0.5 * k}),
        "/m": ("std_msgs/msg/Float32MultiArray", lambda k: {"layout": {"dim": [
            {"label": "row", "size": 2, "stride": 6}, {"label": "a,b,c", "size": 3, "stride": 3}]},
            "data": [k, 1, 2, 3, 4, 5]}),
    }  # fmt: skip
    with open(path, "wb") as f, Writer(f) as w:
        schemas = {tp: w.register_msgdef(kind, ts.generate_msgdef(kind, ros_version=2)[0])
                   for tp, (kind, _) in msgs.items()}  # fmt: skip
        for k in range(3):
            for tp, (_, make) in msgs.items():
                w.write_message(tp, schemas[tp], make(k), log_time=7 * 10**9 + k, publish_time=0)
    sig = read_mcap(path, {tp: tp[1:] for tp in msgs})
    for name in ("odom", "pwc"):
        assert sig[name].values[2].tolist() == [2.0, 2.0, 3.0, 0.0, 0.0, 0.6, 0.8]
        assert sig[name].t.tolist() == [100 + 5e-9, 101 + 5e-9, 102 + 5e-9]
    assert sig["pt"].values[1].tolist() == [1, -1, 0] and sig["vec"].names == ("x", "y", "z")
    assert sig["f"].values.tolist() == [0.0, 0.5, 1.0]
    assert sig["f"].t.tolist() == [7.0, 7.0 + 1e-9, 7.0 + 2e-9]  # no header: the log time
    assert sig["m"].values.shape == (3, 2, 3) and sig["m"].names == ("a", "b", "c")
    assert sig["m"].values[1, 1].tolist() == [3, 4, 5]


def test_export_rejects_bad_images_and_topics(run_dir, tmp_path):
    frame = np.zeros((2, 2, 3), np.uint8)
    with pytest.raises(ExportError, match="images"):
        export_run(run_dir, tmp_path / "a.mcap", images={"C_X": ([0.0], [frame])})
    with pytest.raises(ExportError, match="increasing"):
        export_run(run_dir, tmp_path / "a.mcap", images={"C_L": ([0.2, 0.1], [frame, frame])})
    with pytest.raises(ExportError, match="uint8"):
        export_run(run_dir, tmp_path / "a.mcap", images={"C_L": ([0.1], [frame.astype(float)])})
    assert not (tmp_path / "a.mcap").exists()  # checked before writing
    with pytest.raises(ExportError, match="topics"):
        export_run(run_dir, tmp_path / "a.mcap", topics=["/joint_states"])


def test_frames_of_several_rods_are_prefixed():
    from tdacm import dual_paper_system
    from tdacm.live.messages import _section_frames

    (b1, f1), (b2, f2) = _section_frames(dual_paper_system(), 3)
    assert (b1, b2) == ("rod1_base", "rod2_base")
    assert [f[:2] for f in f1] == [("rod1_1", "rod1_base"), ("rod1_2", "rod1_1"), ("tip", "rod1_2")]
    assert [f[0] for f in f2] == ["rod2_1", "rod2_2", "rod2_tip"] and f2[-1][2] == 1.0


def test_import_errors_name_the_topic(tmp_path):
    from mcap.writer import Writer as McapWriter

    from tdacm.recording import RecordingError

    path = tmp_path / "mixed.mcap"
    with open(path, "wb") as f, Writer(f) as w:
        arr = w.register_msgdef("std_msgs/msg/Float64MultiArray", ARRAY_DEF)
        for k, n in enumerate((3, 3, 4)):  # a message longer than the others
            w.write_message("/v", arr, {"data": [1.0] * n}, log_time=k, publish_time=k)
    with pytest.raises(RecordingError, match="/v"):
        read_mcap(path, {"/v": "v"})
    with pytest.raises(RecordingError, match="one signal name"):
        read_mcap(path, {"/v": {"position": "v"}})  # a table for a non-JointState topic
    path = tmp_path / "joints.mcap"
    with open(path, "wb") as f, Writer(f) as w:
        js = w.register_msgdef("sensor_msgs/msg/JointState", JOINT_DEF)
        w.write_message("/j", js, {"name": ["a"], "effort": [1.0]}, log_time=0, publish_time=0)
    with pytest.raises(RecordingError, match="'pos' is not a JointState field"):
        read_mcap(path, {"/j": {"pos": "x"}})
    assert read_mcap(path, {"/j": "x"})["x"].values.tolist() == [[1.0]]  # the non-empty field
    path = tmp_path / "json.mcap"
    with open(path, "wb") as f:
        w = McapWriter(f)
        w.start()
        sid = w.register_schema("Thing", "jsonschema", b"{}")
        cid = w.register_channel("/json", "json", sid)
        w.add_message(cid, 0, b"{}", 0)
        w.finish()
    with pytest.raises(RecordingError, match="not ROS 2"):
        read_mcap(path, {"/json": "thing"})

"""Watching a run live (docs/live.md): ``tdacm run --live`` publishes the topics of the MCAP
export to a Foxglove WebSocket client as the run goes; the run is the same with or without it."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tdacm.cli import main
from tdacm.live import (
    DEFAULT_TOPICS,
    LAYOUT,
    PROGRESS_TOPIC,
    LiveError,
    LiveRun,
    LiveServer,
    RealTime,
    RobotMessages,
    parse_address,
)
from tdacm.live.client import FoxgloveClient, free_port
from tdacm.live.messages import feature_marker
from tdacm.live.msgdefs import DEFINITIONS
from tdacm.recording import export_run, load_run_folder
from tdacm.sim import Simulation, load_scenario

pytest.importorskip("foxglove")
typesys = pytest.importorskip("rosbags.typesys")
TS = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)
SRC = str(Path(__file__).resolve().parents[2] / "src")
FAST = '[cameras]\nlocal_renderer = "analytic"\nglobal_renderer = "planar"\n'


def _cli(*args) -> subprocess.Popen:
    """``tdacm ARGS`` in a new process (this checkout's sources), its output in pipes."""
    env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.Popen([sys.executable, "-m", "tdacm.cli", *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip


def _arrays(run_dir) -> dict:
    with np.load(Path(run_dir) / "timeseries.npz") as z:
        return {k: z[k] for k in z.files}


# ------------------------------------------------------------------ the acceptance run
@pytest.fixture(scope="module")
def live_run(tmp_path_factory):
    """``tdacm run paper-in-fov --live PORT --duration 2 --realtime`` with a client subscribed
    to the transforms, the tip camera's image, its features and the progress; the client leaves
    before the end (a client that disconnects costs the run nothing). Paced to the wall clock so
    that the run lasts at least its 2 s after the client subscribes, however fast the machine
    (unpaced, a quick run could end before the client's third transform)."""
    out = tmp_path_factory.mktemp("live") / "run"
    port = free_port()
    proc = _cli("run", "paper-in-fov", "--live", str(port), "--duration", "2", "--realtime",
                "--out", str(out))  # fmt: skip
    try:
        client = FoxgloveClient(port)
        wanted = ["/tf", "/tf_static", "/tdacm/C_L/image_raw", "/tdacm/C_L/features",
                  PROGRESS_TOPIC]  # fmt: skip
        assert client.wait_for(lambda: all(t in client.channels for t in wanted), 300), (
            client.channels,
            proc.poll(),
        )
        client.subscribe(wanted)
        msgs = client.messages
        client.wait_for(
            lambda: (
                len(msgs.get("/tf", [])) >= 3
                and "/tdacm/C_L/image_raw" in msgs
                and PROGRESS_TOPIC in msgs
            ),
            120,
        )
        running = proc.poll() is None  # received while the command goes on
        client.close()
        stdout, stderr = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
    return {"out": out, "client": client, "code": proc.returncode, "running": running,
            "stdout": stdout, "stderr": stderr}  # fmt: skip


def test_a_client_receives_the_transforms_and_the_tip_image_during_the_run(live_run):
    assert live_run["code"] == 0, live_run["stderr"]
    assert live_run["running"], "the messages came after the run"
    msgs = live_run["client"].messages
    sim_t = _arrays(live_run["out"])["t"]
    tf = [TS.deserialize_cdr(p, "tf2_msgs/msg/TFMessage") for _, p, _ in msgs["/tf"]]
    assert len(tf) >= 3
    for (log_time, _, _), m in zip(msgs["/tf"], tf, strict=True):
        kids = [x.child_frame_id for x in m.transforms]
        assert kids[0] == "base_link" and kids[-1] == "tip" and len(kids) == 11
        assert m.transforms[0].header.frame_id == "world"
        st = m.transforms[0].header.stamp
        assert st.sec * 10**9 + st.nanosec == log_time
        # stamped at a control step of the run (integer nanoseconds of t)
        assert np.min(np.abs(sim_t * 1e9 - log_time)) <= 1.0
        for x in m.transforms:  # unit quaternions
            r = x.transform.rotation
            assert abs(np.hypot(np.hypot(r.x, r.y), np.hypot(r.z, r.w)) - 1) < 1e-12
    static = TS.deserialize_cdr(msgs["/tf_static"][0][1], "tf2_msgs/msg/TFMessage")
    assert {x.child_frame_id for x in static.transforms} >= {"rod_base", "C_L_optical", "target"}
    img = TS.deserialize_cdr(msgs["/tdacm/C_L/image_raw"][0][1], "sensor_msgs/msg/Image")
    cam = load_run_folder(live_run["out"]).robot.local_camera
    assert (img.width, img.height, img.encoding) == (cam.width, cam.height, "rgb8")
    assert img.header.frame_id == "C_L_optical" and len(img.data) == 3 * img.width * img.height
    assert np.ptp(np.asarray(img.data)) > 50  # a picture, not a blank frame
    marker = TS.deserialize_cdr(msgs["/tdacm/C_L/features"][0][1],
                                "visualization_msgs/msg/ImageMarker")  # fmt: skip
    assert marker.header.frame_id == "C_L_optical" and len(marker.points) == 4  # in view
    progress = [json.loads(p) for _, p, _ in msgs[PROGRESS_TOPIC]]
    assert progress and progress[0]["scenario"] == "paper-in-fov"
    assert any(p["state"] == "running" and p["fraction"] < 1 for p in progress)  # sent mid-run
    assert all(0 <= p["fraction"] <= 1 and p["duration"] == 2.0 for p in progress)


def test_live_messages_are_the_exported_messages(live_run, tmp_path):
    """The transforms published live are, byte for byte, those ``tdacm export`` writes for the
    same steps (one set of builders, the same CDR)."""
    from mcap.reader import make_reader

    path = export_run(live_run["out"], tmp_path / "run.mcap", topics={"/tf", "/tf_static"})
    with open(path, "rb") as f:
        exported = {(ch.topic, m.log_time): m.data
                    for _, ch, m in make_reader(f).iter_messages()}  # fmt: skip
    live = live_run["client"].messages
    for topic in ("/tf", "/tf_static"):
        for log_time, payload, _ in live[topic]:
            assert exported[(topic, log_time)] == payload, (topic, log_time)


def test_a_run_is_the_same_with_and_without_live(live_run, tmp_path):
    """Bit for bit: every logged series of the live run (a client connected, then gone)
    equals the same run without a server."""
    sc = load_scenario("paper-in-fov")
    Simulation(sc, duration=2.0).run(tmp_path / "plain")
    a, b = _arrays(live_run["out"]), _arrays(tmp_path / "plain")
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    s_live = json.loads(live_run["stdout"])
    s_plain = json.loads((tmp_path / "plain" / "summary.json").read_text())
    for k in ("final_rmse", "final_q", "time_to_0.01", "max_tension"):
        assert s_live[k] == s_plain[k], k


def test_a_server_nobody_watches_publishes_nothing_and_changes_nothing(tmp_path):
    sc = load_scenario("ground-test-a", None).with_overrides(
        {"cameras": {"local_renderer": "analytic", "global_renderer": "planar"}}, "test"
    )
    with LiveServer(port=0) as server:
        sim = Simulation(sc, duration=0.3)
        sim.build()
        server.attach(RobotMessages.of_world(sim.assembly.world))
        watched, _ = sim.run(on_step=LiveRun(server, sim.loop, 0.3, sc.name))
        assert server.published == 0 and server.subscriptions == 0
    plain, _ = Simulation(sc, duration=0.3).run()
    for k in plain:
        np.testing.assert_array_equal(watched[k], plain[k], err_msg=k)


# ------------------------------------------------------------------ the command line
def test_a_port_in_use_is_one_error_line(tmp_path, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        code = main(["run", "paper-in-fov", "--live", str(port), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("error: --live ") and "in use" in err[0], err
    assert not (tmp_path / "o").exists()  # nothing run


@pytest.mark.parametrize("bad", ["abc", "70000", "host:", ":", "-1"])
def test_a_malformed_address_exits_2(bad, capsys):
    with pytest.raises(SystemExit) as info:
        main(["run", "paper-in-fov", "--live", bad])
    assert info.value.code == 2
    assert "--live" in capsys.readouterr().err


def test_addresses_default_to_this_machine_only():
    assert parse_address("8765") == ("127.0.0.1", 8765)
    assert parse_address("0.0.0.0:9000") == ("0.0.0.0", 9000)
    assert parse_address("[::1]:8765") == ("::1", 8765)
    assert parse_address("localhost:0") == ("localhost", 0)
    with pytest.raises(LiveError):
        parse_address("8765:x")
    with LiveServer(port=0) as server:
        assert server.host == "127.0.0.1" and server.port > 0
        addrs = _listening(server.port)
        assert addrs == {"0100007F"}, addrs  # 127.0.0.1 only, no IPv4 or IPv6 wildcard


def _listening(port: int) -> set[str]:
    """The local addresses (hex, as in /proc/net/tcp and tcp6) listening on ``port``."""
    out = set()
    for name in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(name) as f:
            for line in list(f)[1:]:
                local, state = line.split()[1], line.split()[3]
                addr, p = local.split(":")
                if state == "0A" and int(p, 16) == port:  # LISTEN
                    out.add(addr)
    return out


def test_replay_streams_a_stored_run(live_run):
    port = free_port()
    proc = _cli("replay", str(live_run["out"]), "--live", str(port), "--speed", "4")
    try:
        client = FoxgloveClient(port)
        topics = ["/tdacm/tendons", "/tf", PROGRESS_TOPIC]
        assert client.wait_for(lambda: all(t in client.channels for t in topics), 120)
        client.subscribe(topics)
        client.wait_for(lambda: False, 5)  # until the stream ends and the server stops
        code = proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert code == 0, proc.stderr.read()
    a = _arrays(live_run["out"])
    msgs = client.messages["/tdacm/tendons"]
    assert len(msgs) >= 2
    for log_time, payload, _ in msgs:  # the stored tensions of that step
        m = TS.deserialize_cdr(payload, "sensor_msgs/msg/JointState")
        k = int(np.argmin(np.abs(a["t"] * 1e9 - log_time)))
        np.testing.assert_array_equal(m.effort, a["u"][k, -4:])
    # the stream waited for the client: it got the first step and the last one
    assert msgs[0][0] == 0 and msgs[-1][0] == round(a["t"][-1] * 1e9)
    # paced at 4 x real time: 2 s of run took at least 0.5 s on the streaming side's clock
    last = json.loads(client.messages[PROGRESS_TOPIC][-1][1])
    assert last["state"] == "done" and last["t"] == a["t"][-1]
    assert last["wall_time"] >= a["t"][-1] / 4


# ------------------------------------------------------------------ pacing
class _Step:
    def __init__(self, t, done=False):
        self.t, self.done = t, done


def test_realtime_paces_to_the_wall_clock():
    pace = RealTime(0.02)
    t0 = time.perf_counter()
    for k in range(26):  # 0.5 s of periods
        pace(_Step(0.02 * k, done=k == 25))
    wall = time.perf_counter() - t0
    assert wall >= 0.5 - 1e-3  # never faster than the wall clock (sleep waits at least)
    assert not pace.lagging


def test_realtime_says_once_when_the_run_is_slower(caplog):
    pace = RealTime(0.01, lag_notice_s=0.05)
    with caplog.at_level("WARNING", logger="tdacm.live"):
        for k in range(12):
            pace(_Step(0.01 * k))
            time.sleep(0.02)  # a period takes twice its simulated time
    notes = [r for r in caplog.records if "slower than" in r.getMessage()]
    assert len(notes) == 1 and pace.lagging and pace.max_lag > 0.05


def test_realtime_run_takes_its_simulated_time(tmp_path):
    """``--realtime``: a 1 s run takes at least 1 s of wall time in the loop (the upper end,
    within 5 % of the duration when the machine keeps up, is measured in
    benchmarks/bench_live.py: a test on a shared machine cannot check it without flaking)."""
    out = tmp_path / "rt"
    assert main(["-q", "run", "ground-test-a", "--config", str(_fast(tmp_path)), "--duration",
                 "1", "--realtime", "--out", str(out)]) == 0  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    assert summary["wall_time_s"] >= 1.0 - 0.02  # the last period is not waited for


def _fast(tmp_path) -> Path:
    p = tmp_path / "fast.toml"
    p.write_text(FAST)
    return p


# ------------------------------------------------------------------ messages and layout
def test_quaternions_are_those_of_the_rotations():
    from scipy.spatial.transform import Rotation

    from tdacm.live.messages import _quat

    mats = [*Rotation.random(2000, random_state=1).as_matrix(), np.eye(3),
            np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])]  # fmt: skip
    for m in mats:  # the half turns: each branch of Shepperd's method
        q = _quat(m)
        assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-15
        assert np.abs(Rotation.from_quat(q).as_matrix() - m).max() < 2e-15


def test_publishing_keeps_to_its_share_of_the_wall_clock():
    """After a publish that took ``c`` seconds the next one waits ``c / share``: a client
    costs a run at most ``share / (1 - share)`` of its time."""
    with LiveServer(port=0, share=0.1) as server:
        server.messages = _SlowMessages(0.005)
        server._channels = {"/tf": _Sink()}
        server.messages.topics = {"/tf": "tf2_msgs/msg/TFMessage"}
        server._encoders = {"tf2_msgs/msg/TFMessage": lambda m: b"x"}
        t0 = time.perf_counter()
        busy = last = 0.0
        while time.perf_counter() - t0 < 1.0:
            a = time.thread_time()  # this thread's CPU: not the time another process took
            if server.publish(0.0, {"q": np.zeros(2)}):
                last = time.thread_time() - a
                busy += last
        wall = time.perf_counter() - t0
    assert server.published >= 2
    # the share, plus the last publish: its wait falls after the second
    assert busy / wall <= 0.1 + last / wall


class _Sink:
    def has_sinks(self):
        return True

    def log(self, data, log_time=None):
        pass


class _SlowMessages:
    """Message builders that take ``cost`` seconds of CPU a step."""

    cameras = ()

    def __init__(self, cost):
        self.cost = cost

    def step(self, ns, row, topics):
        end = time.thread_time() + self.cost
        while time.thread_time() < end:
            pass
        return [("/tf", {})]


def test_feature_marker_draws_the_points_in_pixels():
    from tdacm.vision import PinholeCamera

    cam = PinholeCamera(fx=500.0, fy=400.0, cx=320.0, cy=240.0, width=640, height=480)
    pts = np.array([[0.0, 0.0], [0.1, -0.2], [np.nan, np.nan], [-0.3, 0.05]])
    m = feature_marker(5, "C_L_optical", cam, pts)
    got = [(p["x"], p["y"]) for p in m["points"]]
    assert got == [(320.0, 240.0), (370.0, 160.0), (170.0, 260.0)]  # u = fx x + cx, v = fy y + cy
    assert m["type"] == 4 and len(m["outline_colors"]) == 3
    raw = TS.serialize_cdr(TS.deserialize_cdr(bytes(_encode(m)), "visualization_msgs/msg/ImageMarker"),
                           "visualization_msgs/msg/ImageMarker")  # fmt: skip
    assert raw.tobytes() == bytes(_encode(m))


def _encode(msg):
    from mcap_ros2._dynamic import serialize_dynamic

    from tdacm.live.msgdefs import schema_text

    kind = "visualization_msgs/msg/ImageMarker"
    return serialize_dynamic(kind, schema_text(kind))[kind](msg)


def test_the_shipped_layout_shows_the_published_topics_and_fields():
    layout = json.loads(LAYOUT.read_text())
    cfg = layout["configById"]
    kinds = {p.split("!")[0] for p in cfg}
    assert kinds == {"3D", "Image", "Plot", "RawMessages"}
    image = next(v for k, v in cfg.items() if k.startswith("Image!"))["imageMode"]
    assert image["imageTopic"] == "/tdacm/C_L/image_raw"
    assert set(image["annotations"]) == {"/tdacm/C_L/features"}
    assert image["calibrationTopic"] == "/tdacm/C_L/camera_info"
    for key, panel in cfg.items():
        for path in panel.get("paths", []):  # "/topic.field[i]": a field of the topic's type
            topic, field = path["value"].split(".", 1)
            kind = DEFAULT_TOPICS[topic]
            fields = [ln.split()[1] for ln in DEFINITIONS[kind].splitlines()]
            assert field.split("[")[0] in fields, (key, path["value"])
    assert cfg["RawMessages!tdacm-progress"]["topicPath"] == PROGRESS_TOPIC
    # every panel of configById is placed in the layout tree
    placed, stack = set(), [layout["layout"]]
    while stack:
        node = stack.pop()
        if isinstance(node, str):
            placed.add(node)
        else:
            stack += [node["first"], node["second"]]
    assert placed == set(cfg)


# ------------------------------------------------------------------ the Gymnasium env
def test_the_env_publishes_a_policy_acting_and_acts_the_same(monkeypatch):
    """``render_mode="foxglove"``: each step goes to a subscribed client (the steps the rate
    lets through, and the last one of the episode); the episode is the one without it."""
    gym = pytest.importorskip("gymnasium")
    import tdacm.envs  # noqa: F401  (registers the env)

    actions = np.random.default_rng(3).uniform(-0.3, 0.3, size=(8, 6))

    def episode(env, between=None):
        obs = [env.reset(seed=5)[0]]
        rewards = []
        for a in actions:
            o, r, term, trunc, _ = env.step(a)
            obs.append(o)
            rewards.append(r)
            if between is not None:
                between()
            if term or trunc:
                break
        return np.array(obs), np.array(rewards)

    watched = gym.make("tdacm/TipServo-v0", max_steps=8, render_mode="foxglove", live="0")
    env = watched.unwrapped
    assert env.live.host == "127.0.0.1" and env.render() is None
    client = FoxgloveClient(env.live.port)
    topics = ["/tf", "/tdacm/servo/feature_error", PROGRESS_TOPIC]
    env.reset(seed=5)  # the channels are advertised at the first reset
    assert client.wait_for(lambda: all(t in client.channels for t in topics), 30)
    client.subscribe(topics)
    client.wait_for(lambda: env.live.subscribed() >= set(topics[:2]), 5)

    def pause():  # a policy slower than the publishing: every step goes out
        while not env.live.due():
            client.poll(0.005)

    obs_w, rew_w = episode(env, pause)

    def ended():
        last = client.messages.get(PROGRESS_TOPIC, [])[-1:]
        return last and json.loads(last[0][1])["state"] == "done"

    assert client.wait_for(ended, 5)  # the episode's last progress message, after its last step
    watched.close()
    plain = gym.make("tdacm/TipServo-v0", max_steps=8)
    obs_p, rew_p = episode(plain.unwrapped)
    plain.close()
    np.testing.assert_array_equal(obs_w, obs_p)
    np.testing.assert_array_equal(rew_w, rew_p)
    stamps = [lt for lt, _, _ in client.messages["/tf"]]
    dt = env.loop.dt
    assert stamps == [round(k * dt * 1e9) for k in range(len(rew_w))]  # one per step, in order
    err = TS.deserialize_cdr(client.messages["/tdacm/servo/feature_error"][0][1],
                             "std_msgs/msg/Float64MultiArray")  # fmt: skip
    assert err.layout.dim[0].label == "e_p_phi,e_p_theta,e_p_psi,e_p_x,e_p_y,e_p_z"


def test_the_env_refuses_an_address_without_foxglove():
    from tdacm.envs.servo import TipServoEnv

    with pytest.raises(ValueError, match="live: a server address needs render_mode='foxglove'"):
        TipServoEnv(live="8765")


def test_a_paced_run_publishes_in_its_spare_time():
    """Past its share, a step still goes out when the run has more time to spare before its
    next period than the last publish took, and not when it has less."""
    with LiveServer(port=0, share=0.1) as server:
        server.messages = _SlowMessages(0.01)
        server._channels = {"/tf": _Sink()}
        server.messages.topics = {"/tf": "tf2_msgs/msg/TFMessage"}
        server._encoders = {"tf2_msgs/msg/TFMessage": lambda m: b"x"}
        assert server.publish(0.0, {"q": np.zeros(2)})
        time.sleep(1.5 / server.rate_hz)  # the rate allows the next one, the share does not
        assert not server.due()
        assert not server.due(slack=0.5 * server.last_cost)
        assert server.due(slack=2 * server.last_cost)
        assert server.publish(0.02, {"q": np.zeros(2)}, slack=2 * server.last_cost)
        assert not server.due(slack=1.0)  # the rate still holds

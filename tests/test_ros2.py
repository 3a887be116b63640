"""uavmpc on a ROS 2 graph (rmw_zenoh's wire format), shown without a ROS installation.

An in-test Zenoh router stands for ``rmw_zenohd``. An observer finds uavmpc's publishers only
through their liveliness tokens (as rmw_zenoh's graph cache does), subscribes by the key
expressions those tokens name, checks every attachment, and decodes every payload with an
independent CDR implementation (mcap-ros2-support's, from the message definition text).
Golden values come from rmw_zenoh's design document.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("xxhash")
pytest.importorskip("zenoh")
pytest.importorskip("mcap_ros2")

import zenoh
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic
from waiting import wait_until

from uavmpc import scenarios
from uavmpc.comms import ros2
from uavmpc.comms.zenoh_link import ZenohTransport, loopback_router
from uavmpc.drivers.node import Node
from uavmpc.drivers.swarm import free_ports, run_swarm
from uavmpc.plant import Airframe
from uavmpc.scenarios.run import RunSpec

pytestmark = pytest.mark.realtime  # flies on the wall clock

# From rmw_zenoh's docs/design.md (its talker example, ROS_DOMAIN_ID 2).
TALKER_TOKEN = ("@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
                "std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db128802"
                "1743503259e948f6b1a18/::,7:,:,:,,")
STRING_KEY = ("0/chatter/std_msgs::msg::dds_::String_/"
              "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")
# Hashes of the types we publish, as ROS 2 Jazzy reports them (`ros2 topic info -v`).
GOLDEN_HASHES = {
    "std_msgs/msg/String":
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "geometry_msgs/msg/PoseStamped":
        "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "nav_msgs/msg/Odometry":
        "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "nav_msgs/msg/Path": "RIHS01_1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b",
}


def test_keys_tokens_hashes_and_gids_are_rmw_zenohs() -> None:
    codec = ros2.Ros2Codec()
    for ros_type, golden in GOLDEN_HASHES.items():
        assert codec.type_hash(ros_type) == golden
    string = "std_msgs/msg/String"
    assert ros2.topic_key(0, "/chatter", ros2.dds_type_name(string),
                          codec.type_hash(string)) == STRING_KEY
    assert ros2.liveliness_token(
        2, "8b20917502ee955ac4476e0266340d5c", 0, 10, "MP", "/", "talker",
        ("/chatter", ros2.dds_type_name(string), codec.type_hash(string), "::,7:,:,:,,")
    ) == TALKER_TOKEN
    # rmw_zenoh's GID of that entity: XXH3-128 of the token (computed with its own code).
    assert ros2.gid_of(TALKER_TOKEN).hex() == "ac170f31eadcd9ff0cd86d7a17907d1c"
    assert ros2.mangle("/uav1/pose") == "%uav1%pose"


def test_ros_and_our_quaternions_round_trip() -> None:
    q = np.array([0.7, 0.1, -0.2, 0.68])
    assert np.array_equal(ros2.our_quat(*ros2.ros_quat(q)), q)


def test_the_avoidance_status_carries_what_the_prediction_messages_do() -> None:
    from types import SimpleNamespace

    from uavmpc.avoidance.strategy import AvoidanceDecision
    from uavmpc.drivers.ros2 import publish_status

    codec = ros2.Ros2Codec()
    kind = ros2.AVOIDANCE_STATUS
    # the new fields follow the old ones, in the definition rclpy / mcap readers are given
    fields = [line.split()[1] for line in codec.definition(kind).split("\n=")[0].splitlines()
              if line.strip() and not line.startswith("#")]
    assert fields == ["header", "active", "z_offset_m", "yielding_to", "heard",
                      "position_sigma_horizontal_m", "position_sigma_vertical_m", "holding",
                      "deaf", "broken"]
    independent = generate_dynamic(kind, codec.definition(kind))[kind]  # mcap-ros2-support
    cdr = codec.avoidance_status(12.5, True, 1.5, ["uav2"], heard=("uav2", "uav3"),
                                 position_sigma_horizontal_m=0.8, position_sigma_vertical_m=1.2,
                                 holding=True, deaf=("uav3",),
                                 broken=("A3 estimate: vertical σ 2.50 m > 1.5 m",))
    for msg in (codec.decode(cdr, kind), independent(cdr)):
        assert (msg.active, msg.z_offset_m, list(msg.yielding_to)) == (True, 1.5, ["uav2"])
        assert list(msg.heard) == ["uav2", "uav3"] and list(msg.deaf) == ["uav3"]
        assert (msg.position_sigma_horizontal_m, msg.position_sigma_vertical_m) == (0.8, 1.2)
        assert msg.holding is True
        assert list(msg.broken) == ["A3 estimate: vertical σ 2.50 m > 1.5 m"]
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 500_000_000)
    assert codec.encode(codec.decode(cdr, kind), kind) == cdr
    # the callers of before: nothing heard, no uncertainty stated, not holding, none deaf
    old = codec.decode(codec.avoidance_status(0.0, False, 0.0, []), kind)
    assert (list(old.heard), old.position_sigma_horizontal_m, old.position_sigma_vertical_m,
            old.holding, list(old.deaf), list(old.broken)) == ([], 0.0, 0.0, False, [], [])
    # an id list given as one string would go out letter by letter: refused by name
    with pytest.raises(TypeError, match="heard: a sequence of strings"):
        codec.avoidance_status(0.0, False, 0.0, [], heard="uav2")
    with pytest.raises(TypeError, match="deaf: a sequence of strings"):
        codec.avoidance_status(0.0, False, 0.0, [], deaf=b"uav2")
    with pytest.raises(TypeError, match="broken: a sequence of strings"):
        codec.avoidance_status(0.0, False, 0.0, [], broken="A4 vehicle")
    with pytest.raises(ValueError, match="could not convert"):
        codec.avoidance_status(0.0, False, 0.0, [], position_sigma_vertical_m="high")

    # a stack's status, as the drivers publish it: its decision's and its messages' values
    class Topics:
        def __init__(self) -> None:
            self.codec = codec
            self.sent: list[bytes] = []

        publish_avoidance = ros2.UavTopics.publish_avoidance

    class Sink:
        def __init__(self, sent: list[bytes]) -> None:
            self.put = lambda cdr, _t_ns: sent.append(cdr)

    topics = Topics()
    topics.avoidance = Sink(topics.sent)
    decision = AvoidanceDecision(z_offset_m=2.0, avoiding=True, yielding_to=("uav1",),
                                 deaf=("uav4",), holding=True)
    stack = SimpleNamespace(steering=SimpleNamespace(decision=decision), heard=("uav1", "uav4"),
                            position_sigma_m=(0.5, 0.9),
                            tracker=SimpleNamespace(z_offset_m=2.0))
    publish_status(topics, 3.0, stack, ("A4 vehicle: tracking 3.40 m > 3 m",))
    stack.steering.decision, stack.heard = None, ()  # before its first decision and broadcast
    publish_status(topics, 3.1, stack)
    first, before = (codec.decode(c, kind) for c in topics.sent)
    assert (first.active, first.z_offset_m, list(first.yielding_to)) == (True, 2.0, ["uav1"])
    assert list(first.heard) == ["uav1", "uav4"] and list(first.deaf) == ["uav4"]
    assert first.holding is True and list(first.broken) == ["A4 vehicle: tracking 3.40 m > 3 m"]
    assert (first.position_sigma_horizontal_m, first.position_sigma_vertical_m) == (0.5, 0.9)
    assert (before.active, list(before.heard), before.holding, list(before.deaf)) == (
        False, [], False, [])
    assert (before.position_sigma_horizontal_m, before.position_sigma_vertical_m) == (0.5, 0.9)


def _router() -> tuple[object, str]:
    (port,) = free_ports(1)
    return loopback_router(port), f"tcp/127.0.0.1:{port}"


class Observer:
    """A ROS 2-like client of the router: discovers by liveliness, subscribes by key, decodes
    with mcap-ros2-support."""

    def __init__(self, endpoint: str) -> None:
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"client"')
        cfg.insert_json5("connect/endpoints", f'["{endpoint}"]')
        self.session = zenoh.open(cfg)
        self.codec = ros2.Ros2Codec()
        self.samples: dict[str, list[tuple[float, bytes, bytes | None]]] = defaultdict(list)
        self.lock = threading.Lock()
        self.subs = []

    def tokens(self, prefix: str = "@ros2_lv/0/**") -> list[str]:
        return [str(r.ok.key_expr) for r in self.session.liveliness().get(prefix, timeout=2.0)
                if r.ok is not None]

    def follow(self, token: str) -> tuple[str, str]:
        """Subscribe to the data of the entity a token announces; (topic, ROS type)."""
        parts = token.split("/")
        assert parts[0] == "@ros2_lv" and len(parts) >= 13 and parts[5] == "MP"
        topic = parts[9].replace("%", "/")
        type_name, type_hash = parts[10], parts[11]
        pkg, kind, rest = type_name.split("::")[0], type_name.split("::")[1], type_name
        ros_type = f"{pkg}/{kind}/{rest.split('::')[-1].rstrip('_')}"
        key = f"{parts[1]}/{topic.strip('/')}/{type_name}/{type_hash}"

        def on(sample: object) -> None:
            att = sample.attachment.to_bytes() if sample.attachment is not None else None
            with self.lock:
                self.samples[topic].append((time.time(), bytes(sample.payload.to_bytes()), att))

        self.subs.append(self.session.declare_subscriber(key, on))
        return topic, ros_type

    def decoder(self, ros_type: str):
        return generate_dynamic(ros_type, self.codec.definition(ros_type))[ros_type]

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()
        self.session.close()


def test_a_node_on_the_graph_is_found_followed_decoded_and_commanded() -> None:
    router, endpoint = _router()
    ports = free_ports(1)
    tx = ZenohTransport("uav1", swarm=f"r{ports[0]}", listen=[f"tcp/127.0.0.1:{ports[0]}"])
    graph = ros2.Ros2Graph(endpoint, node_name="uavmpc_uav1")
    topics = ros2.UavTopics(graph, "uav1")
    node = Node("uav1", 1, Airframe.packaged("f550"), tx, start_m=(0.0, 0.0, 5.0), ros2=topics)
    thread = threading.Thread(target=node.run, args=(16.0,), daemon=True)
    obs = Observer(endpoint)
    try:
        thread.start()

        def announced() -> list[str] | None:  # the graph, once the node's last topic is on it
            now = obs.tokens()
            return now if any("/MP/" in t and "uavmpc_uav1" in t and "%avoidance" in t
                              for t in now) else None

        tokens = wait_until(announced, 30.0, "the node's publishers on the graph")
        nodes = [t for t in tokens if "/NN/" in t]
        assert any(t.endswith("/NN/%/%/uavmpc_uav1") for t in nodes), tokens
        pubs = [t for t in tokens if "/MP/" in t and "uavmpc_uav1" in t]
        subs = [t for t in tokens if "/MS/" in t and "uavmpc_uav1" in t]
        followed = dict(obs.follow(t) for t in pubs)
        assert set(followed) == {"/uav1/pose", "/uav1/odom", "/uav1/prediction",
                                 "/uav1/avoidance"}
        assert {t.split("/")[9] for t in subs} == {"%uav1%goal", "%uav1%trajectory"}
        t_end = time.time() + 900.0  # the node's clock starts once its kernels are loaded
        while not obs.samples["/uav1/pose"] and time.time() < t_end:
            time.sleep(0.1)
        t_watch = time.time()
        time.sleep(3.0)
        # A goal, published as a ROS 2 node would: its own token, CDR by an independent
        # encoder, rmw_zenoh's attachment.
        goal_type = "geometry_msgs/msg/PoseStamped"
        goal_key = ros2.topic_key(0, "/uav1/goal", ros2.dds_type_name(goal_type),
                                  obs.codec.type_hash(goal_type))
        encode_goal = serialize_dynamic(goal_type, obs.codec.definition(goal_type))[goal_type]
        token = ros2.liveliness_token(0, str(obs.session.info.zid()), 0, 1, "MP", "/", "mission",
                                      ("/uav1/goal", ros2.dds_type_name(goal_type),
                                       obs.codec.type_hash(goal_type), ros2.QOS_KEEP_LAST_10))
        live = obs.session.liveliness().declare_token(token)
        gid = ros2.gid_of(token)

        def put(payload: bytes, seq: int) -> None:
            att = seq.to_bytes(8, "little") + time.time_ns().to_bytes(8, "little") + b"\x10" + gid
            obs.session.put(goal_key, payload, attachment=att)

        stamp = {"sec": 0, "nanosec": 0}
        put(b"\x00\x01\x00\x00garbage", 1)  # malformed CDR
        put(encode_goal({"header": {"stamp": stamp, "frame_id": "map"},  # a frame we refuse
                         "pose": {"position": {"x": 9.0, "y": 9.0, "z": 9.0},
                                  "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}), 2)
        put(encode_goal({"header": {"stamp": stamp, "frame_id": "world"},
                         "pose": {"position": {"x": 6.0, "y": -3.0, "z": 7.0},
                                  "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}), 3)
        thread.join(timeout=120)
        assert not thread.is_alive(), "the node's 16 s flight did not end"
        live.undeclare()
    finally:
        obs.close()
        graph.close()
        tx.close()
        router.close()
    stats = node.stats
    assert stats.missions_rejected == 2  # the garbage and the wrong frame, counted
    assert np.linalg.norm(np.array(stats.final_position_m) - [6.0, -3.0, 7.0]) < 0.3
    with obs.lock:
        samples = dict(obs.samples)
    for topic, ros_type in followed.items():
        decode = obs.decoder(ros_type)
        got = samples[topic]
        seqs = []
        for _, payload, att in got:
            assert payload[:4] == b"\x00\x01\x00\x00"
            assert att is not None and len(att) == 33 and att[16] == 16
            seqs.append(int.from_bytes(att[:8], "little"))
            assert att[17:] == ros2.gid_of(next(t for t in pubs if ros2.mangle(topic) in t))
            decode(payload)  # every message decodes against its definition
        assert seqs == sorted(seqs) and seqs[0] >= 1
    # they kept coming while the node flew (rates: `uavmpc bench ros2`, not asserted here)
    assert [t for t, _, _ in samples["/uav1/pose"] if t_watch <= t <= t_watch + 3.0]
    assert [t for t, _, _ in samples["/uav1/prediction"] if t_watch <= t]
    path = obs.decoder("nav_msgs/msg/Path")(samples["/uav1/prediction"][-1][1])
    assert len(path.poses) == 40 and path.header.frame_id == "world"
    odom = obs.decoder("nav_msgs/msg/Odometry")(samples["/uav1/odom"][-1][1])
    assert odom.child_frame_id == "uav1/base_link"
    status = obs.decoder("uavmpc_msgs/msg/AvoidanceStatus")(samples["/uav1/avoidance"][-1][1])
    assert status.active is False and list(status.yielding_to) == []
    # alone, it heard nobody and holds short of nobody; the uncertainty its messages state
    assert list(status.heard) == [] and status.holding is False and list(status.deaf) == []
    # (it widens with the tracking error: a simulated plant's is millimetres)
    stated = node.stack.position_sigma_m
    assert status.position_sigma_horizontal_m == pytest.approx(stated[0], abs=0.005)
    assert status.position_sigma_vertical_m == pytest.approx(stated[1], abs=0.005)
    assert stated[0] < 0.05 and stated[1] < 0.05


def test_without_commands_no_subscription_is_offered() -> None:
    router, endpoint = _router()
    try:
        with ros2.Ros2Graph(endpoint, node_name="uavmpc_k") as graph:
            ros2.UavTopics(graph, "k", commands=False)
            obs = Observer(endpoint)
            time.sleep(0.5)
            tokens = obs.tokens()
            obs.close()
        assert [t for t in tokens if "/MP/" in t] and not [t for t in tokens if "/MS/" in t]
    finally:
        router.close()


def _listening_sockets() -> set[tuple[str, int]]:
    """(address, port) of the TCP sockets this process listens on (from /proc)."""
    import os
    import socket

    mine = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            link = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if link.startswith("socket:["):
            mine.add(link[8:-1])
    out = set()
    for table, family in (("/proc/net/tcp", socket.AF_INET), ("/proc/net/tcp6", socket.AF_INET6)):
        with open(table) as f:
            for line in f.readlines()[1:]:
                fields = line.split()
                if fields[3] != "0A" or fields[9] not in mine:  # 0A: LISTEN
                    continue
                addr_hex, port_hex = fields[1].split(":")
                raw = bytes.fromhex(addr_hex)
                # /proc writes each 32-bit word in host (little-endian) order
                raw = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
                out.add((socket.inet_ntop(family, raw), int(port_hex, 16)))
    return out


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux's /proc")
def test_the_graph_publishes_reliably_and_listens_on_loopback_only() -> None:
    router, endpoint = _router()
    before = _listening_sockets()
    try:
        with ros2.Ros2Graph(endpoint, node_name="uavmpc_r") as graph:
            topics = ros2.UavTopics(graph, "r", commands=False)
            # the token says reliable (empty first QoS field) and so does the publisher
            assert "/::,10:,:,:,," in topics.pose.token_key
            assert topics.pose.reliability == zenoh.Reliability.RELIABLE
            opened = _listening_sockets() - before
            assert opened and all(addr == "127.0.0.1" for addr, _ in opened), opened
        with ros2.Ros2Graph(endpoint, node_name="uavmpc_n", listen=()):
            assert _listening_sockets() - before == set()
        with pytest.raises(ValueError, match="listen"):
            ros2.Ros2Graph(endpoint, listen=["localhost"])
    finally:
        router.close()


def test_a_swarm_on_the_graph_publishes_every_uavs_topics(tmp_path: Path) -> None:
    router, endpoint = _router()
    obs = Observer(endpoint)
    followed: dict[str, str] = {}
    result: dict = {}

    def fly() -> None:
        result["summary"] = (run_swarm(
            RunSpec(scenarios.load("swap_through_static"), duration_s=10.0), tmp_path,
            ros2=endpoint))

    thread = threading.Thread(target=fly, daemon=True)
    try:
        thread.start()
        t_end = time.time() + 600.0  # node processes compile their kernels on a cold cache
        while len(followed) < 9 and time.time() < t_end:  # 3 UAVs × pose, odom, prediction
            for token in obs.tokens():
                topic = token.split("/")[9].replace("%", "/") if "/MP/" in token else ""
                if topic.rsplit("/", 1)[-1] in ("pose", "odom", "prediction") \
                        and topic not in followed:
                    followed[topic] = obs.follow(token)[1]
            time.sleep(0.5)
        while time.time() < t_end and not all(obs.samples[f"/{u}/pose"]
                                              for u in ("uav1", "uav2", "uav3")):
            time.sleep(0.1)
        t_watch = time.time()
        time.sleep(4.0)
        with obs.lock:
            samples = {k: [t for t, _, _ in v if t_watch <= t <= t_watch + 4.0]
                       for k, v in obs.samples.items()}
        thread.join(timeout=600)
        assert not thread.is_alive(), "the swarm's 10 s flight did not end within 600 s"
    finally:
        obs.close()
        router.close()
    assert not result["summary"].collisions
    for uav in ("uav1", "uav2", "uav3"):  # every topic of every UAV kept coming (rates:
        for kind in ("pose", "odom", "prediction"):  # `uavmpc bench ros2`, not asserted here)
            assert samples[f"/{uav}/{kind}"], (uav, kind)


def test_a_run_exports_as_a_rosbag2_that_independent_readers_read(tmp_path: Path,
                                                                   capsys) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.rosbag2 import Reader

    from uavmpc.apps.cli import main

    run = tmp_path / "run"
    assert main(["run", "swap_through_static", "--duration", "4", "--out", str(run)]) == 0
    with (run / "flight.mcap").open("rb") as fh:
        # the per-UAV channels; the link events and the Foxglove scene and metrics stay in
        # the MCAP (no ROS 2 type of ours carries them)
        source = [(c.topic, m.log_time) for _, c, m in make_reader(fh).iter_messages()
                  if c.topic not in ("/link", "/scene", "/metrics")]
    assert main(["export-bag", str(run)]) == 0
    bag = run / "rosbag2"
    with (bag / "rosbag2.mcap").open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        decoded = [(c.topic, s.name, m.log_time, d)
                   for s, c, m, d in reader.iter_decoded_messages()]
    assert len(decoded) == len(source)
    renamed = {"state": "pose", "status": "avoidance"}
    want: dict[str, int] = defaultdict(int)
    for topic, _ in source:
        uav, kind = topic.strip("/").split("/")
        want[f"/{uav}/{renamed.get(kind, kind)}"] += 1
    got: dict[str, int] = defaultdict(int)
    for topic, *_ in decoded:
        got[topic] += 1
    assert got == want
    types = {topic.rsplit("/", 1)[-1]: name for topic, name, _, _ in decoded}
    assert types == {"pose": "geometry_msgs/msg/PoseStamped",
                     "command": "geometry_msgs/msg/PoseStamped",
                     "reference": "geometry_msgs/msg/PoseStamped",
                     "prediction": "nav_msgs/msg/Path",
                     "avoidance": "uavmpc_msgs/msg/AvoidanceStatus"}
    times = [t for _, _, t, _ in decoded]
    assert (min(times), max(times)) == (min(t for _, t in source), max(t for _, t in source))
    path = next(d for topic, _, _, d in decoded if topic.endswith("prediction"))
    assert len(path.poses) == 40 and path.poses[1].header.stamp.nanosec != \
        path.poses[0].header.stamp.nanosec
    with Reader(bag) as r:  # rosbag2's metadata.yaml, read by rosbags
        assert r.message_count == len(source)
    capsys.readouterr()
    assert main(["export-bag", str(run)]) == 2  # an existing bag is not overwritten silently
    assert "--overwrite" in capsys.readouterr().err


def test_the_simulated_world_in_real_time_is_on_the_graph_and_takes_goals() -> None:
    from uavmpc.drivers.ros2 import WorldOnRos2
    from uavmpc.drivers.world import World

    router, endpoint = _router()
    sc = scenarios.load("swap_through_static")
    world = World(RunSpec(sc))
    result: dict = {}
    try:
        with ros2.Ros2Graph(endpoint, node_name="uavmpc_world") as graph:
            mirror = WorldOnRos2(graph, [u.uav_id for u in sc.uavs])
            obs = Observer(endpoint)
            thread = threading.Thread(
                target=lambda: result.update(r=world.run(7.0, realtime=1.0, on_log=mirror)),
                daemon=True)
            thread.start()

            def poses() -> list[str] | None:
                now = [t for t in obs.tokens() if "/MP/" in t and "%pose/" in t]
                return now if len(now) >= 3 else None

            tokens = wait_until(poses, 30.0, "the world's three pose publishers on the graph")
            assert len(tokens) == 3 and all("/uavmpc_world/" in t for t in tokens)
            obs.follow(next(t for t in tokens if "%uav1%pose" in t))
            goal_type = "geometry_msgs/msg/PoseStamped"
            encode = serialize_dynamic(goal_type, obs.codec.definition(goal_type))[goal_type]
            key = ros2.topic_key(0, "/uav3/goal", ros2.dds_type_name(goal_type),
                                 obs.codec.type_hash(goal_type))
            att = (1).to_bytes(8, "little") + time.time_ns().to_bytes(8, "little") + b"\x10" + \
                bytes(16)
            obs.session.put(key, encode({"header": {"stamp": {"sec": 0, "nanosec": 0},
                                                    "frame_id": "world"},
                                         "pose": {"position": {"x": 0.0, "y": 6.0, "z": 5.0},
                                                  "orientation": {"x": 0.0, "y": 0.0, "z": 0.0,
                                                                  "w": 1.0}}}),
                            attachment=att)
            # A cold first run compiles the world's kernels inside this thread (minutes on a
            # loaded 2-core machine): bound the wait generously and say so if it runs out.
            thread.join(timeout=900)
            assert not thread.is_alive(), "the world's 7 s flight did not end within 900 s"
            with obs.lock:
                poses = list(obs.samples["/uav1/pose"])
            obs.close()
    finally:
        router.close()
    r = result["r"]
    assert mirror.missions_taken == 1 and not mirror.missions_rejected
    # It flew there (its height is the avoidance's: uav1 and uav2 still pass above it).
    assert np.linalg.norm(np.array(r.per_uav["uav3"].final_position_m[:2]) - [0.0, 6.0]) < 0.5
    assert poses  # uav1's pose was on the graph while the world flew
    decode = obs.decoder(goal_type)
    stamp = decode(poses[-1][1]).header.stamp
    assert abs(stamp.sec + stamp.nanosec * 1e-9 - time.time()) < 60.0  # wall-clock stamps


def test_trajectories_from_ros2_become_validated_references() -> None:
    from uavmpc.drivers.ros2 import ros2_mission
    from uavmpc.reference import InvalidReferenceError

    codec = ros2.Ros2Codec()
    path_type = "nav_msgs/msg/Path"
    encode = serialize_dynamic(path_type, codec.definition(path_type))[path_type]

    def path(stamps: list[float], xs: list[float], frame: str = "world") -> bytes:
        poses = [{"header": {"stamp": {"sec": int(t), "nanosec": round((t % 1) * 1e9)},
                             "frame_id": frame},
                  "pose": {"position": {"x": x, "y": 0.0, "z": 5.0},
                           "orientation": {"x": 0.0, "y": 0.0, "z": 0.7071068, "w": 0.7071068}}}
                 for t, x in zip(stamps, xs, strict=True)]
        return encode({"header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": frame},
                       "poses": poses})

    now = 1000.0
    times, pts = codec.trajectory(path([1001.0, 1002.5, 1004.0], [0.0, 5.0, 10.0]))
    ref = ros2_mission(times, pts, now)
    assert np.allclose(ref.knots_s, [1001.0, 1002.5, 1004.0])
    assert np.allclose(ref.values[:, 3], np.pi / 2, atol=1e-6)  # heading from the orientation
    times, pts = codec.trajectory(path([0.0, 0.0, 0.0], [0.0, 1.0, 2.0]))  # no stamps:
    ref = ros2_mission(times, pts, now)  # sampled every 0.2 s from now
    assert np.allclose(ref.sample(np.array([now + 0.2]))[0, 0], 1.0)
    with pytest.raises(InvalidReferenceError):  # stamps going back: the mission validation
        ros2_mission(*codec.trajectory(path([1003.0, 1002.0], [0.0, 1.0])), now)
    with pytest.raises(ros2.InvalidRosMessageError, match="frame"):
        codec.trajectory(path([1.0, 2.0], [0.0, 1.0], frame="map"))
    with pytest.raises(ros2.InvalidRosMessageError, match="no poses"):
        codec.trajectory(encode({"header": {"stamp": {"sec": 0, "nanosec": 0},
                                            "frame_id": "world"}, "poses": []}))

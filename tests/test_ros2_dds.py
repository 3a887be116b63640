"""uavmpc on ROS 2's DDS middleware, checked against real ROS 2 (issue 29).

Two parts:
- Cyclone DDS alone (no ROS install): names, USER_DATA type hash, ``ros_discovery_info``, the
  CDR carried through unchanged, a bad command refused and counted.
- Real ROS 2 Jazzy rclpy from PyPI, on Fast DDS (ROS 2's default middleware), in a venv of its
  own built once and cached (``rclpy_env.py``), run as a subprocess (``rclpy_probe.py``): it
  sees a swarm's topics, types, hashes and nodes, receives its messages, publishes a goal that
  a UAV flies; and every message type uavmpc writes (on its Zenoh topics, in ``export-bag``,
  and its discovery message) round-trips through ``rclpy.serialization``. Skipped, with the
  reason, where that venv cannot be built.

No rate or latency is asserted here: ``benchmarks/ros2_dds_rates.py`` measures them.
"""

from __future__ import annotations

import dataclasses
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("cyclonedds")
pytest.importorskip("zenoh")

from rclpy_env import rclpy_python, run_probe
from waiting import wait_until

from uavmpc import scenarios
from uavmpc.comms import dds, ros2
from uavmpc.drivers.ros2 import open_graph, ros2_mission
from uavmpc.drivers.swarm import free_ports, run_swarm
from uavmpc.scenarios.run import RunSpec

pytestmark = pytest.mark.realtime  # discovery and flights on the wall clock

UAVS = ("uav1", "uav2", "uav3")
TYPES = {"pose": ros2.POSE, "odom": ros2.ODOMETRY, "prediction": ros2.PATH,
         "avoidance": ros2.AVOIDANCE_STATUS, "goal": ros2.POSE, "trajectory": ros2.PATH}


def _domain() -> int:
    """A DDS domain of this test run's own, away from 0 (other ROS 2 users on the machine)."""
    return 100 + os.getpid() % 100


@pytest.fixture(scope="module")
def rclpy_py() -> Path:
    python, why = rclpy_python()
    if python is None:
        pytest.skip(why)
    return python


def _plain(msg: Any) -> Any:
    """A rosbags message as the JSON values the probe gives for rclpy's."""
    if dataclasses.is_dataclass(msg):
        return {f.name: _plain(getattr(msg, f.name)) for f in dataclasses.fields(msg)
                if not f.name.startswith("__")}  # rosbags' __msgtype__
    if isinstance(msg, np.ndarray | list | tuple):
        return [_plain(v) for v in msg]
    return msg.item() if isinstance(msg, np.generic) else msg


# ---------------------------------------------------------------------- Cyclone DDS alone

def test_names_and_the_type_hash_in_user_data_are_ros2s() -> None:
    assert dds.dds_topic_name("/uav1/pose") == "rt/uav1/pose"
    assert ros2.dds_type_name(ros2.POSE) == "geometry_msgs::msg::dds_::PoseStamped_"
    assert dds.user_data("RIHS01_ab") == b"typehash=RIHS01_ab;"
    with pytest.raises(ValueError, match="starts with '/'"):
        dds.dds_topic_name("uav1/pose")
    with pytest.raises(ValueError, match="domain id"):
        open_graph("dds/x", "uavmpc_a")


def test_the_node_is_announced_and_cdr_goes_through_unchanged_and_bad_commands_count() -> None:
    domain = _domain()
    with dds.DdsGraph(domain, node_name="uavmpc_a") as a, \
            dds.DdsGraph(domain, node_name="uavmpc_b") as b:
        topics = ros2.UavTopics(a, "a")
        info = a.codec.decode(a.participant_info(), dds.PARTICIPANT_INFO)
        assert bytes(info.gid.data) == a.gid
        (node,) = info.node_entities_info_seq
        assert (node.node_namespace, node.node_name) == ("/", "uavmpc_a")
        writers = {bytes(g.data) for g in node.writer_gid_seq}
        readers = {bytes(g.data) for g in node.reader_gid_seq}
        assert writers == {topics.pose.gid, topics.odom.gid, topics.prediction.gid,
                           topics.avoidance.gid}
        assert readers == {topics.goal.gid, topics.trajectory.gid}
        goal = b.publisher("/a/goal", ros2.POSE)
        good = a.codec.pose_stamped(0.0, np.array([1.0, 2.0, 3.0]), np.array([1.0, 0, 0, 0]))
        got: list[bytes] = []

        def delivered() -> bool:  # discovery first: put until the reader has something
            goal.put(good)
            got.extend(topics.goal.drain())
            return bool(got)

        wait_until(delivered, 30.0, "a goal across two participants", poll_s=0.2)
        assert got[0] == good  # the codec's bytes, unchanged
        # Unflyable: another frame, a position that is not a number. (Malformed CDR never
        # reaches us: Cyclone checks every sample's CDR against its type and drops it.)
        types = a.codec.types
        for frame, x in (("map", 1.0), ("world", float("nan"))):
            goal.put(a.codec.encode(types[ros2.POSE](
                header=a.codec.header(0.0, frame),
                pose=types["geometry_msgs/msg/Pose"](
                    position=types["geometry_msgs/msg/Point"](x=x, y=0.0, z=5.0),
                    orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0,
                                                                       w=1.0))), ros2.POSE))
        taken: list[Any] = []
        rejected: list[str] = []

        def refused() -> bool:
            missions, why = topics.missions(
                5.0, lambda times, points: ros2_mission(times, points, 5.0))
            taken.extend(missions)
            rejected.extend(why)
            return len(rejected) >= 2

        wait_until(refused, 10.0, "both unflyable goals, refused")
        assert not taken and len(rejected) == 2
        assert "frame_id 'map'" in rejected[0], rejected
        assert "goto[0]: must be a finite number" in rejected[1], rejected
        # A trajectory (nav_msgs/Path, stamps zero: one pose every 0.2 s from now) is taken.
        trajectory = b.publisher("/a/trajectory", ros2.PATH)
        points = np.array([[0.0, 0.0, 5.0], [1.0, 0.0, 5.0], [2.0, 1.0, 5.5]])
        trajectory.put(a.codec.path(0.0, np.zeros(3), points, np.zeros(3)))

        def flown() -> list[Any]:
            missions, why = topics.missions(
                5.0, lambda times, pts: ros2_mission(times, pts, 5.0))
            assert not why
            return missions

        (reference,) = wait_until(flown, 10.0, "the trajectory, taken")
        assert np.allclose(reference.sample(np.array([5.4]))[0, :3], [2.0, 1.0, 5.5])


# ---------------------------------------------------------------------- real rclpy

def _zenoh_payloads() -> dict[str, bytes]:
    """One message of each topic a UAV publishes, as it arrived on a Zenoh router."""
    from uavmpc.comms.zenoh_link import loopback_router

    (port,) = free_ports(1)
    router = loopback_router(port)
    got: dict[str, bytes] = {}
    try:
        with ros2.Ros2Graph(f"tcp/127.0.0.1:{port}", node_name="uavmpc_z") as graph:
            sub = graph.session.declare_subscriber(
                "0/z/**", lambda s: got.setdefault(str(s.key_expr).split("/")[2],
                                                   bytes(s.payload.to_bytes())))
            topics = ros2.UavTopics(graph, "z", commands=False)
            q = np.array([0.9, 0.1, -0.3, 0.3]) / np.linalg.norm([0.9, 0.1, -0.3, 0.3])

            def publish() -> bool:
                topics.publish_state(12.5, np.array([1.0, -2.0, 3.5]), np.array([0.5, 0, 0.1]),
                                     q, np.array([0.01, 0.02, -0.03]))
                topics.publish_prediction(12.5, 12.5 + 0.2 * np.arange(40),
                                          np.linspace([0, 0, 5], [8, 1, 6], 40),
                                          np.linspace(0, 1, 40))
                topics.publish_avoidance(12.5, True, 1.5, ["uav2"])
                return len(got) == 4

            wait_until(publish, 20.0, "every topic's sample on the router", poll_s=0.1)
            sub.undeclare()
    finally:
        router.close()
    return got


def _bag_payloads(tmp_path: Path) -> list[tuple[str, str, bytes]]:
    """(topic, ROS type, CDR) of one message per topic of an exported run."""
    from mcap.reader import make_reader

    from uavmpc.apps.cli import main

    run = tmp_path / "run"
    assert main(["run", "swap_through_static", "--duration", "1", "--out", str(run)]) == 0
    assert main(["export-bag", str(run)]) == 0
    seen: dict[str, tuple[str, str, bytes]] = {}
    with (run / "rosbag2" / "rosbag2.mcap").open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            seen.setdefault(channel.topic, (channel.topic, schema.name, bytes(message.data)))
    return list(seen.values())


def test_every_message_uavmpc_writes_round_trips_through_real_rclpy(rclpy_py: Path,
                                                                    tmp_path: Path) -> None:
    codec = ros2.Ros2Codec()
    messages = [(f"zenoh /z/{k}", TYPES[k], cdr) for k, cdr in _zenoh_payloads().items()]
    messages += _bag_payloads(tmp_path)
    with dds.DdsGraph(_domain(), node_name="uavmpc_rt") as graph:
        ros2.UavTopics(graph, "rt")
        messages.append(("ros_discovery_info", dds.PARTICIPANT_INFO, graph.participant_info()))
    kinds = {t for _, t, _ in messages}
    assert kinds == {ros2.POSE, ros2.ODOMETRY, ros2.PATH, ros2.AVOIDANCE_STATUS,
                     dds.PARTICIPANT_INFO}
    # Our own AvoidanceStatus has no rclpy class unless uavmpc_msgs is built in a ROS
    # workspace (colcon, a compiler): its standard parts are what rclpy reads.
    known = [m for m in messages if m[1] != ros2.AVOIDANCE_STATUS]
    answer = run_probe(rclpy_py, {"op": "roundtrip", "messages": [
        {"type": t, "cdr": cdr.hex()} for _, t, cdr in known]}, domain_id=_domain())
    assert len(answer["messages"]) == len(known)
    for (where, ros_type, cdr), back in zip(known, answer["messages"], strict=True):
        mine = codec.decode(cdr, ros_type)
        # rclpy read every field as we wrote it ...
        assert back["message"] == _plain(mine), where
        # ... and its own CDR of it is ours, byte for byte (once its unwritten padding is
        # normalised by decoding and encoding again)
        assert codec.encode(codec.decode(bytes.fromhex(back["cdr"]), ros_type),
                            ros_type) == cdr, where
    assert {w.rsplit("/", 1)[-1] for w, _, _ in messages if w.startswith("/")} == {
        "pose", "command", "reference", "prediction", "avoidance"}  # the bag's topics


def test_a_swarm_on_dds_is_seen_by_real_rclpy_and_flies_its_goal(rclpy_py: Path,
                                                                 tmp_path: Path) -> None:
    domain = _domain()
    result: dict = {}
    goal = [-25.0, 4.0, 6.0]  # uav1 starts at (-25, 0, 5); it has the right of way

    def fly() -> None:
        result["summary"] = (run_swarm(
            RunSpec(scenarios.load("swap_through_static"), duration_s=32.0), tmp_path,
            ros2=f"dds/{domain}"))

    thread = threading.Thread(target=fly, daemon=True)
    thread.start()
    try:
        seen = run_probe(rclpy_py, {"op": "watch", "uavs": list(UAVS), "seconds": 4.0,
                                    "timeout": 60.0, "goal": {"uav": "uav1", "position": goal,
                                                              "within_m": 0.5}},
                         domain_id=domain, timeout_s=150.0)
    finally:
        thread.join(timeout=120)
    assert seen["all_data"] and seen["goal_matched"]
    codec = ros2.Ros2Codec()
    topics = {name: types for name, types in seen["topics"]}
    for uav in UAVS:
        for kind, ros_type in TYPES.items():
            assert topics.get(f"/{uav}/{kind}") == [ros_type], (uav, kind)
        assert ["/", f"uavmpc_{uav}"] in seen["nodes"]
        for kind in ("pose", "odom", "prediction"):
            topic = f"/{uav}/{kind}"
            (pub,) = seen["publishers"][topic]
            assert pub == {"node": f"uavmpc_{uav}", "type": TYPES[kind],
                           "hash": codec.type_hash(TYPES[kind]), "reliability": "RELIABLE",
                           "durability": "VOLATILE"}
            assert seen["times"][topic], topic  # it arrived
        pose = seen["last"][f"/{uav}/pose"]
        assert pose["header"]["frame_id"] == "world"
        q = pose["pose"]["orientation"]
        assert abs(np.linalg.norm([q["x"], q["y"], q["z"], q["w"]]) - 1.0) < 1e-6
        path = seen["last"][f"/{uav}/prediction"]["poses"]
        assert len(path) == 40 and path[0]["header"]["stamp"] != path[1]["header"]["stamp"]
        odom = seen["last"][f"/{uav}/odom"]
        assert odom["child_frame_id"] == f"{uav}/base_link"
    # flown there, as rclpy sees it (the swarm flies on to its end at 32 s: a bound, not a wait)
    assert seen["goal_distance_m"] < 0.5
    assert not result["summary"].collisions
    uav1 = result["summary"].uavs["uav1"]
    assert np.linalg.norm(np.array(uav1.final_position_m) - goal) < 0.5  # and stayed
    assert uav1.details["node"]["missions_rejected"] >= 2  # the goal in frame map, the empty path

"""A real ROS 2 node (rclpy, ROS 2's default DDS middleware) that looks at uavmpc (test helper).

Runs in the rclpy venv of ``rclpy_env.py``, never in the project's. Reads one JSON request on
stdin, prints one JSON answer line on stdout:

- ``{"op": "roundtrip", "messages": [{"type": "pkg/msg/Name", "cdr": hex}, ...]}``: each message
  deserialized by ``rclpy.serialization`` into rclpy's own class and serialized again; answers,
  per message, rclpy's CDR (hex) and the message as a dict.
- ``{"op": "watch", "uavs": [...], "seconds": S, "timeout": T, "goal": {...}}``: subscribes
  to every UAV's pose, odom and prediction; once every one has data, publishes the goal (and
  the bad commands) and records S more seconds, then waits (at most T) until the UAV's pose is
  within ``within_m`` of the goal; answers the graph (topics and types, nodes,
  publishers' type hashes and QoS), per topic the receive times (Unix s), the messages' header
  stamps, the DDS source-to-received times and the last message.
"""

from __future__ import annotations

import importlib
import json
import sys
import time
from typing import Any

import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from rclpy.serialization import deserialize_message, serialize_message

KINDS = {"pose": PoseStamped, "odom": Odometry, "prediction": Path}


def get_message(ros_type: str) -> Any:
    """rclpy's class of ``pkg/msg/Name``."""
    pkg, _, name = ros_type.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def as_dict(msg: Any) -> Any:
    """A message as plain JSON values (rosidl_runtime_py is not on PyPI)."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {f: as_dict(getattr(msg, f)) for f in msg.get_fields_and_field_types()}
    if isinstance(msg, list | tuple) or type(msg).__name__ == "ndarray":
        return [as_dict(v) for v in msg]
    if isinstance(msg, bytes):
        return list(msg)
    return msg if isinstance(msg, bool | int | float | str) else msg.item()


def roundtrip(request: dict[str, Any]) -> dict[str, Any]:
    out = []
    for m in request["messages"]:
        cls = get_message(m["type"])
        cdr = bytes.fromhex(m["cdr"])
        msg = deserialize_message(cdr, cls)
        # Fast CDR leaves its alignment padding unwritten (not zero): the caller compares
        # these bytes after decoding them itself
        out.append({"type": m["type"], "cdr": serialize_message(msg).hex(),
                    "message": as_dict(msg)})
    return {"messages": out}


def _spin_until(node: Any, condition: Any, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return True
        rclpy.spin_once(node, timeout_sec=0.05)
    return bool(condition())


def _goal(frame: str, x: float, y: float, z: float) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, z
    msg.pose.orientation.w = 1.0
    return msg


def watch(request: dict[str, Any]) -> dict[str, Any]:
    node = rclpy.create_node("uavmpc_probe")
    times: dict[str, list[float]] = {}
    stamps: dict[str, list[float]] = {}
    wire: dict[str, list[float]] = {}
    last: dict[str, Any] = {}
    for uav in request["uavs"]:
        for kind, cls in KINDS.items():
            topic = f"/{uav}/{kind}"
            times[topic] = []
            stamps[topic] = []
            wire[topic] = []

            def on(msg: Any, info: Any, topic: str = topic) -> None:
                times[topic].append(time.time())
                stamps[topic].append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
                # DDS's own stamps: written by the publisher, received by the middleware
                wire[topic].append((info["received_timestamp"] - info["source_timestamp"]) * 1e-9)
                last[topic] = msg

            node.create_subscription(cls, topic, on, 10)
    started = _spin_until(node, lambda: all(times.values()), request["timeout"])
    answer: dict[str, Any] = {"all_data": started}
    goal = request.get("goal")
    if started and goal is not None:
        pub = node.create_publisher(PoseStamped, f"/{goal['uav']}/goal", 10)
        bad_path = node.create_publisher(Path, f"/{goal['uav']}/trajectory", 10)
        answer["goal_matched"] = _spin_until(
            node, lambda: pub.get_subscription_count() > 0
            and bad_path.get_subscription_count() > 0, request["timeout"])
        _spin_until(node, lambda: False, 1.0)  # let the other side match us too
        x, y, z = goal["position"]
        pub.publish(_goal("map", x, y, z))  # a frame uavmpc refuses
        empty = Path()
        empty.header.frame_id = "world"
        bad_path.publish(empty)  # a path without poses
        pub.publish(_goal("world", x, y, z))
    t0 = time.time()
    _spin_until(node, lambda: time.time() - t0 >= request["seconds"], request["seconds"] + 1)
    if started and goal is not None:  # then until the UAV is there, as its pose tells
        topic = f"/{goal['uav']}/pose"

        def away() -> float:
            p = last[topic].pose.position
            return sum((a - b) ** 2 for a, b in zip((p.x, p.y, p.z), goal["position"],
                                                    strict=True)) ** 0.5

        _spin_until(node, lambda: away() < goal["within_m"], request["timeout"])
        answer["goal_distance_m"] = away()
    answer["topics"] = sorted([name, types] for name, types in node.get_topic_names_and_types())
    answer["nodes"] = sorted([ns, name] for name, ns in node.get_node_names_and_namespaces())
    answer["publishers"] = {}
    for topic in times:
        answer["publishers"][topic] = [
            {"node": i.node_name, "type": i.topic_type, "hash": str(i.topic_type_hash),
             "reliability": i.qos_profile.reliability.name,
             "durability": i.qos_profile.durability.name}
            for i in node.get_publishers_info_by_topic(topic)]
    answer["times"] = times
    answer["stamps"] = stamps
    answer["wire_s"] = wire
    answer["last"] = {t: as_dict(m) for t, m in last.items()}
    node.destroy_node()
    return answer


def main() -> int:
    request = json.loads(sys.stdin.read())
    rclpy.init()
    try:
        answer = roundtrip(request) if request["op"] == "roundtrip" else watch(request)
    finally:
        rclpy.shutdown()
    print(json.dumps(answer))
    return 0


if __name__ == "__main__":
    sys.exit(main())

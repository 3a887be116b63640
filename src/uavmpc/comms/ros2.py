"""uavmpc on a ROS 2 graph, over rmw_zenoh's wire format, without a ROS installation.

ROS 2 Jazzy's Zenoh middleware (rmw_zenoh ≥ 0.2.4; Rolling ≥ 0.6.0) puts every message as a
Zenoh sample, and finds nodes and topics through Zenoh liveliness tokens. This module speaks that
format (optional extra ``uavmpc[ros2]``):

- **data**: key ``<domain>/<topic without its leading />/<pkg>::msg::dds_::<Type>_/RIHS01_<hash>``,
  payload CDR (little endian, with its 4-byte encapsulation header), and an attachment of
  33 bytes: sequence number (int64 LE, from 1), source time stamp [ns] (int64 LE), the byte 16
  and the 16-byte GID;
- **graph**: one token per node ``@ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<ns>/<name>``
  and per publisher (``MP``) or subscriber (``MS``) the same with ``/<topic>/<type>/<hash>/<qos>``
  appended; every ``/`` inside a field is written ``%``; the GID is the XXH3-128 of the token;
- **session**: a Zenoh peer connected to a router (ROS 2's ``rmw_zenohd``, default
  ``tcp/localhost:7447``), multicast scouting off, as rmw_zenoh configures its sessions.

Messages are built, encoded and hashed (RIHS01) by ``rosbags`` (a maintained pure-Python ROS
library); our own type ``uavmpc_msgs/msg/AvoidanceStatus`` is defined by the shipped
``data/msg/AvoidanceStatus.msg``. Conventions: ROS's are ours (REP 103: world ENU, body FLU), but
a ROS quaternion is ``(x, y, z, w)``; that conversion is :func:`ros_quat` / :func:`our_quat`.

Not covered: rmw_zenoh 0.2.0–0.2.3 (their attachment had string keys), transient-local
durability for late joiners (an AdvancedPublisher cache), services, shared memory.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import resources
from types import ModuleType
from typing import TYPE_CHECKING, Any, Protocol, Self, TypeVar

import numpy as np

if TYPE_CHECKING:
    import zenoh
    from rosbags.typesys.store import Msg, MsgType, Typestore

__all__ = ["AVOIDANCE_STATUS", "InvalidRosMessageError", "Ros2Codec", "Ros2Graph",
           "Ros2Publisher", "Ros2Subscriber", "RosGraph", "TopicReader", "TopicWriter",
           "UavTopics", "dds_type_name", "gid_of", "liveliness_token", "mangle", "our_quat",
           "ros_quat", "topic_key"]

POSE = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
PATH = "nav_msgs/msg/Path"
AVOIDANCE_STATUS = "uavmpc_msgs/msg/AvoidanceStatus"
#: rmw_zenoh's default router endpoint.
DEFAULT_ROUTER = "tcp/localhost:7447"
#: Where the graph session accepts connections from other peers: loopback only, as rmw_zenoh's
#: own session config (it listens on ``tcp/localhost:0``); a port chosen by the system.
DEFAULT_LISTEN = ("tcp/127.0.0.1:0",)
#: The QoS field of a token: reliable, volatile, keep last 10 (empty fields are rmw_zenoh's
#: defaults: reliable, volatile, keep-last, depth 42, infinite durations, automatic liveliness).
QOS_KEEP_LAST_10 = "::,10:,:,:,,"
WORLD_FRAME = "world"

_EXTRA = "pip install 'uavmpc[ros2]'"

#: What a mission built from a ROS 2 goal or trajectory is (the caller's ``build`` says).
M = TypeVar("M")


def _need(module: str) -> ModuleType:
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise ImportError(f"ROS 2 topics need {module.split('.')[0]}: {_EXTRA}") from None


def ros_quat(q_wxyz: np.ndarray) -> tuple[float, float, float, float]:
    """Our ``(w, x, y, z)`` → ROS's ``(x, y, z, w)``."""
    return float(q_wxyz[1]), float(q_wxyz[2]), float(q_wxyz[3]), float(q_wxyz[0])


def our_quat(x: float, y: float, z: float, w: float) -> np.ndarray:
    """ROS's ``(x, y, z, w)`` → our ``(w, x, y, z)``."""
    return np.array([w, x, y, z], dtype=float)


def mangle(name: str) -> str:
    """A name inside a liveliness token: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def dds_type_name(ros_type: str) -> str:
    """``geometry_msgs/msg/PoseStamped`` → ``geometry_msgs::msg::dds_::PoseStamped_``."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


class InvalidRosMessageError(ValueError):
    """A ROS 2 message that does not decode, or whose content we refuse (the text says why)."""


class Ros2Codec:
    """ROS 2 Jazzy message types (rosbags' type store plus uavmpc_msgs), CDR and RIHS01."""

    def __init__(self) -> None:
        typesys = _need("rosbags.typesys")
        self.store: Typestore = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
        text = resources.files("uavmpc.data").joinpath("msg/AvoidanceStatus.msg").read_text()
        self.store.register(typesys.get_types_from_msg(text, AVOIDANCE_STATUS))
        self.types = self.store.types
        self._hashes: dict[str, str] = {}

    def type_hash(self, ros_type: str) -> str:
        """``RIHS01_<64 hex>`` of a type (REP 2011)."""
        if ros_type not in self._hashes:
            self._hashes[ros_type] = self.store.hash_rihs01(ros_type)
        return self._hashes[ros_type]

    def definition(self, ros_type: str) -> str:
        """The ``ros2msg`` definition text (with its dependencies), as MCAP schemas hold it."""
        return self.store.generate_msgdef(ros_type, ros_version=2)[0]

    def encode(self, message: object, ros_type: str) -> bytes:
        return bytes(self.store.serialize_cdr(message, ros_type))

    def decode(self, data: bytes, ros_type: str) -> Any:
        # Any: the message's fields are those of ``ros_type``, known only at run time.
        try:
            return self.store.deserialize_cdr(bytes(data), ros_type)
        except Exception as exc:  # rosbags raises assorted errors on truncated/garbled CDR
            raise InvalidRosMessageError(f"not a {ros_type} in CDR: {exc}") from None

    # ------------------------------------------------------------------ our messages
    def header(self, t_s: float, frame_id: str = WORLD_FRAME) -> MsgType:
        ns = max(0, round(float(t_s) * 1e9))
        t = self.types
        return t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
            frame_id=frame_id)

    def _pose(self, p: np.ndarray, q_wxyz: np.ndarray) -> MsgType:
        t = self.types
        x, y, z, w = ros_quat(q_wxyz)
        return t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
            orientation=t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w))

    def pose_stamped(self, t_s: float, p: np.ndarray, q_wxyz: np.ndarray) -> bytes:
        msg = self.types[POSE](header=self.header(t_s), pose=self._pose(p, q_wxyz))
        return self.encode(msg, POSE)

    def odometry(self, t_s: float, child_frame: str, p: np.ndarray, v_world: np.ndarray,
                 q_wxyz: np.ndarray, w_body: np.ndarray) -> bytes:
        """nav_msgs/Odometry: pose in ``world``, twist in the body frame (``child_frame``), as
        the message defines it."""
        from uavmpc.plant.interface import quat_to_rot

        t = self.types
        v_body = quat_to_rot(q_wxyz).T @ np.asarray(v_world, dtype=float)
        vec = t["geometry_msgs/msg/Vector3"]
        msg = t[ODOMETRY](
            header=self.header(t_s), child_frame_id=child_frame,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=self._pose(p, q_wxyz),
                                                           covariance=np.zeros(36)),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](
                    linear=vec(x=float(v_body[0]), y=float(v_body[1]), z=float(v_body[2])),
                    angular=vec(x=float(w_body[0]), y=float(w_body[1]), z=float(w_body[2]))),
                covariance=np.zeros(36)))
        return self.encode(msg, ODOMETRY)

    def path(self, stamp_s: float, times_s: np.ndarray, positions_m: np.ndarray,
             headings_rad: np.ndarray) -> bytes:
        """nav_msgs/Path of a plan: one stamped pose per point, heading as a yaw quaternion."""
        ps = self.types[POSE]
        poses: list[Msg] = []
        for t_k, p, h in zip(times_s.tolist(), positions_m, headings_rad.tolist(), strict=True):
            q = np.array([math.cos(0.5 * h), 0.0, 0.0, math.sin(0.5 * h)])
            poses.append(ps(header=self.header(t_k), pose=self._pose(p, q)))
        return self.encode(self.types[PATH](header=self.header(stamp_s), poses=poses), PATH)

    def avoidance_status(self, t_s: float, active: bool, z_offset_m: float,
                         yielding_to: Sequence[str], *, heard: Sequence[str] = (),
                         position_sigma_horizontal_m: float = 0.0,
                         position_sigma_vertical_m: float = 0.0, holding: bool = False,
                         deaf: Sequence[str] = (), broken: Sequence[str] = ()) -> bytes:
        """uavmpc_msgs/AvoidanceStatus: what the avoidance does (``active``, ``z_offset_m``,
        ``yielding_to``, ``holding``, ``deaf``), what its prediction messages carry (``heard``,
        the stated position 1 sigma) and the assumptions broken now (``broken``).

        Raises:
            TypeError: an id list given as one string (it would be sent letter by letter).
        """
        msg = self.types[AVOIDANCE_STATUS](
            header=self.header(t_s), active=bool(active), z_offset_m=float(z_offset_m),
            yielding_to=_ids("yielding_to", yielding_to), heard=_ids("heard", heard),
            position_sigma_horizontal_m=float(position_sigma_horizontal_m),
            position_sigma_vertical_m=float(position_sigma_vertical_m), holding=bool(holding),
            deaf=_ids("deaf", deaf), broken=_ids("broken", broken))
        return self.encode(msg, AVOIDANCE_STATUS)

    # ------------------------------------------------------------------ missions
    def goal(self, data: bytes) -> tuple[np.ndarray, float]:
        """A go-to from a geometry_msgs/PoseStamped: (position (3,), heading); its frame must be
        ``world`` (or empty)."""
        msg = self.decode(data, POSE)
        _check_frame(msg.header.frame_id)
        p = msg.pose.position
        o = msg.pose.orientation
        q = our_quat(o.x, o.y, o.z, o.w)
        norm = float(np.linalg.norm(q))
        if not math.isfinite(norm) or norm < 1e-6:
            raise InvalidRosMessageError("goal orientation: not a quaternion (use w = 1 for none)")
        from uavmpc.plant.interface import heading_of

        return np.array([p.x, p.y, p.z], dtype=float), float(heading_of(q / norm))

    def trajectory(self, data: bytes) -> tuple[np.ndarray | None, np.ndarray]:
        """A desired trajectory from a nav_msgs/Path: (absolute times (n,) from the poses'
        stamps, or None when they are all zero; points (n, 4): x, y, z, heading)."""
        msg = self.decode(data, PATH)
        _check_frame(msg.header.frame_id)
        if not msg.poses:
            raise InvalidRosMessageError("trajectory: the path has no poses")
        from uavmpc.plant.interface import heading_of

        pts = np.empty((len(msg.poses), 4))
        stamps = np.empty(len(msg.poses))
        for k, ps in enumerate(msg.poses):
            _check_frame(ps.header.frame_id)
            o = ps.pose.orientation
            q = our_quat(o.x, o.y, o.z, o.w)
            norm = float(np.linalg.norm(q))
            heading = float(heading_of(q / norm)) if math.isfinite(norm) and norm > 1e-6 else 0.0
            pos = ps.pose.position
            pts[k] = (pos.x, pos.y, pos.z, heading)
            stamps[k] = ps.header.stamp.sec + ps.header.stamp.nanosec * 1e-9
        pts[:, 3] = np.unwrap(pts[:, 3])
        return (None if not np.any(stamps) else stamps), pts


def _ids(field: str, ids: Sequence[str]) -> list[str]:
    """A message's list of strings (UAV ids, assumptions); one string alone is refused."""
    if isinstance(ids, str | bytes):
        raise TypeError(f"{field}: a sequence of strings, got one {type(ids).__name__} {ids!r}")
    return [str(u) for u in ids]


def _check_frame(frame_id: str) -> None:
    if frame_id not in ("", WORLD_FRAME):
        raise InvalidRosMessageError(
            f"frame_id {frame_id!r}: uavmpc takes missions in the {WORLD_FRAME!r} frame (ENU)")


# ---------------------------------------------------------------------- the graph

@dataclass
class Ros2Stats:
    published: int = 0
    received: int = 0
    bytes_published: int = 0


class TopicWriter(Protocol):
    """A ROS 2 publisher, over Zenoh or DDS."""

    def put(self, cdr: bytes, t_ns: int | None = None) -> None: ...

    def close(self) -> None: ...


class TopicReader(Protocol):
    """A ROS 2 subscription, over Zenoh or DDS."""

    def drain(self, most: int = 8) -> list[bytes]: ...

    def close(self) -> None: ...


class RosGraph(Protocol):
    """One ROS 2 node on a graph: over rmw_zenoh (:class:`Ros2Graph`) or over DDS
    (:class:`uavmpc.comms.dds.DdsGraph`)."""

    codec: Ros2Codec

    def publisher(self, topic: str, ros_type: str,
                  qos: str = QOS_KEEP_LAST_10) -> TopicWriter: ...

    def subscriber(self, topic: str, ros_type: str, qos: str = QOS_KEEP_LAST_10,
                   maxlen: int = 16) -> TopicReader: ...

    def close(self) -> None: ...

    def __enter__(self) -> Self: ...

    def __exit__(self, *exc: object) -> None: ...


class Ros2Publisher:
    """One ROS 2 publisher: its liveliness token (MP), its key, sequence numbers and GID."""

    def __init__(self, graph: Ros2Graph, topic: str, ros_type: str, qos: str) -> None:
        self.graph = graph
        self.topic = topic
        self.ros_type = ros_type
        self.key = graph.topic_key(topic, ros_type)
        self.token_key = graph.entity_token(next(graph.ids), "MP", topic, ros_type, qos)
        self.gid = gid_of(self.token_key)
        self._seq = 0
        zenoh = _need("zenoh")
        # Reliable, as the token's QoS says and as rmw_zenoh declares its own publishers.
        self._pub = graph.session.declare_publisher(
            self.key, reliability=zenoh.Reliability.RELIABLE)
        self._token = graph.session.liveliness().declare_token(self.token_key)

    def put(self, cdr: bytes, t_ns: int | None = None) -> None:
        """Publish one CDR payload with rmw_zenoh's attachment."""
        import time

        self._seq += 1
        stamp = time.time_ns() if t_ns is None else int(t_ns)
        attachment = (self._seq.to_bytes(8, "little", signed=True)
                      + stamp.to_bytes(8, "little", signed=True) + b"\x10" + self.gid)
        self._pub.put(cdr, attachment=attachment)
        self.graph.stats.published += 1
        self.graph.stats.bytes_published += len(cdr)

    @property
    def reliability(self) -> zenoh.Reliability:
        """The Zenoh reliability this publisher was declared with."""
        return self._pub.reliability

    def close(self) -> None:
        self._token.undeclare()
        self._pub.undeclare()


class Ros2Subscriber:
    """One ROS 2 subscription (MS token): what arrives waits in a bounded queue for
    :meth:`drain` (the oldest dropped first when full)."""

    def __init__(self, graph: Ros2Graph, topic: str, ros_type: str, qos: str,
                 maxlen: int = 16) -> None:
        self.graph = graph
        self.key = graph.topic_key(topic, ros_type)
        self.token_key = graph.entity_token(next(graph.ids), "MS", topic, ros_type, qos)
        self._queue: deque[bytes] = deque(maxlen=maxlen)
        self._lock = threading.Lock()
        self._sub = graph.session.declare_subscriber(self.key, self._on_sample)
        self._token = graph.session.liveliness().declare_token(self.token_key)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self._queue.append(bytes(sample.payload.to_bytes()))
        self.graph.stats.received += 1

    def drain(self, most: int = 8) -> list[bytes]:
        with self._lock:
            return [self._queue.popleft() for _ in range(min(most, len(self._queue)))]

    def close(self) -> None:
        self._token.undeclare()
        self._sub.undeclare()


def graph_identity(domain_id: int | None, node_name: str) -> tuple[int, str]:
    """A graph's ROS domain (None: ``ROS_DOMAIN_ID``, else 0) and node name, checked: the
    same rules for a graph over Zenoh and over DDS.

    Raises:
        ValueError: a domain outside 0..232, or a name ROS does not take.
    """
    if domain_id is None:
        domain_id = int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    if not 0 <= int(domain_id) <= 232:
        raise ValueError(f"domain_id: must be in 0..232, got {domain_id!r}")
    if not node_name or not all(c.isalnum() or c == "_" for c in node_name) \
            or node_name[0].isdigit():
        raise ValueError(f"node_name: ROS names are [A-Za-z_][A-Za-z0-9_]*, got {node_name!r}")
    return int(domain_id), node_name


def gid_of(token_key: str) -> bytes:
    """rmw_zenoh's GID of an entity: XXH3-128 of its token, low 64 bits then high, each LE."""
    xxhash = _need("xxhash")
    return xxhash.xxh3_128_intdigest(token_key.encode()).to_bytes(16, "little")


def liveliness_token(domain_id: int, zid: str, node_id: int, entity_id: int, kind: str,
                     namespace: str, node_name: str,
                     topic: tuple[str, str, str, str] | None = None, enclave: str = "/") -> str:
    """rmw_zenoh's liveliness token of a node (``kind`` NN) or of an entity (MP, MS, SS, SC,
    with ``topic`` = (name, DDS type name, type hash, QoS field))."""
    token = (f"@ros2_lv/{domain_id}/{zid}/{node_id}/{entity_id}/{kind}/{mangle(enclave)}/"
             f"{mangle(namespace)}/{mangle(node_name)}")
    if topic is not None:
        name, type_name, type_hash, qos = topic
        token += f"/{mangle(name)}/{type_name}/{type_hash}/{qos}"
    return token


def topic_key(domain_id: int, topic: str, type_name: str, type_hash: str) -> str:
    """The key expression a topic's data is put on."""
    if not topic.startswith("/"):
        raise ValueError(f"topic: a fully qualified ROS name starts with '/', got {topic!r}")
    return f"{domain_id}/{topic.strip('/')}/{type_name}/{type_hash}"


class Ros2Graph:
    """A Zenoh session on a ROS 2 graph: one ROS node (``node_name`` in ``namespace``) whose
    publishers and subscribers appear in ``ros2 node list`` / ``ros2 topic list``.

    Args:
        router: the Zenoh router to connect to (``rmw_zenohd``).
        node_name: the ROS node's name.
        domain_id: ``ROS_DOMAIN_ID`` (default: that environment variable, else 0).
        namespace: the node's namespace ("/" for none).
        listen: endpoints on which the session accepts peers' connections (default: loopback
            only, a free port); ``()`` for none. Zenoh's own default would be every interface.
    """

    session: zenoh.Session

    def __init__(self, router: str = DEFAULT_ROUTER, *, node_name: str = "uavmpc",
                 domain_id: int | None = None, namespace: str = "/",
                 listen: Sequence[str] = DEFAULT_LISTEN) -> None:
        from uavmpc.comms.zenoh_link import check_endpoints

        zenoh = _need("zenoh")
        (self.router,) = check_endpoints([router], "router")
        self.listen = check_endpoints(listen, "listen")
        self.domain_id, self.node_name = graph_identity(domain_id, node_name)
        self.namespace = namespace
        self.codec = Ros2Codec()
        self.stats = Ros2Stats()
        config = zenoh.Config()
        for key, value in (("mode", '"peer"'), ("connect/endpoints", f'["{self.router}"]'),
                           ("listen/endpoints", json.dumps(self.listen)),
                           ("scouting/multicast/enabled", "false")):
            config.insert_json5(key, value)
        try:
            self.session = zenoh.open(config)
        except zenoh.ZError as exc:
            raise OSError(f"cannot open a Zenoh session to {self.router}: {exc}") from None
        self.zid = str(self.session.info.zid())
        self.ids = itertools.count()
        self.node_id = next(self.ids)
        self._node_token = self.session.liveliness().declare_token(self.node_token())
        self._entities: list[Ros2Publisher | Ros2Subscriber] = []

    def node_token(self) -> str:
        return liveliness_token(self.domain_id, self.zid, self.node_id, self.node_id, "NN",
                                self.namespace, self.node_name)

    def entity_token(self, entity_id: int, kind: str, topic: str, ros_type: str,
                     qos: str) -> str:
        return liveliness_token(self.domain_id, self.zid, self.node_id, entity_id, kind,
                                self.namespace, self.node_name,
                                (topic, dds_type_name(ros_type), self.codec.type_hash(ros_type),
                                 qos))

    def topic_key(self, topic: str, ros_type: str) -> str:
        return topic_key(self.domain_id, topic, dds_type_name(ros_type),
                         self.codec.type_hash(ros_type))

    def publisher(self, topic: str, ros_type: str, qos: str = QOS_KEEP_LAST_10) -> Ros2Publisher:
        pub = Ros2Publisher(self, topic, ros_type, qos)
        self._entities.append(pub)
        return pub

    def subscriber(self, topic: str, ros_type: str, qos: str = QOS_KEEP_LAST_10,
                   maxlen: int = 16) -> Ros2Subscriber:
        sub = Ros2Subscriber(self, topic, ros_type, qos, maxlen)
        self._entities.append(sub)
        return sub

    def close(self) -> None:
        for e in self._entities:
            e.close()
        self._entities.clear()
        self._node_token.undeclare()
        self.session.close()

    def __enter__(self) -> Ros2Graph:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class UavTopics:
    """One UAV's topics on a graph: ``/<id>/pose``, ``/<id>/odom``, ``/<id>/prediction``,
    ``/<id>/avoidance`` out; ``/<id>/goal`` (PoseStamped) and ``/<id>/trajectory`` (Path) in,
    unless ``commands`` is False."""

    def __init__(self, graph: RosGraph, uav_id: str, *, commands: bool = True) -> None:
        self.graph = graph
        self.codec = graph.codec
        self.uav_id = uav_id
        base = f"/{uav_id}"
        self.pose = graph.publisher(f"{base}/pose", POSE)
        self.odom = graph.publisher(f"{base}/odom", ODOMETRY)
        self.prediction = graph.publisher(f"{base}/prediction", PATH)
        self.avoidance = graph.publisher(f"{base}/avoidance", AVOIDANCE_STATUS)
        self.goal = graph.subscriber(f"{base}/goal", POSE) if commands else None
        self.trajectory = graph.subscriber(f"{base}/trajectory", PATH) if commands else None

    def publish_state(self, t_s: float, p: np.ndarray, v: np.ndarray, q_wxyz: np.ndarray,
                      w_body: np.ndarray) -> None:
        ns = round(t_s * 1e9)
        self.pose.put(self.codec.pose_stamped(t_s, p, q_wxyz), ns)
        self.odom.put(self.codec.odometry(t_s, f"{self.uav_id}/base_link", p, v, q_wxyz, w_body),
                      ns)

    def publish_prediction(self, stamp_s: float, times_s: np.ndarray, positions_m: np.ndarray,
                           headings_rad: np.ndarray) -> None:
        self.prediction.put(self.codec.path(stamp_s, times_s, positions_m, headings_rad),
                            round(stamp_s * 1e9))

    def publish_avoidance(self, t_s: float, active: bool, z_offset_m: float,
                          yielding_to: Sequence[str], *, heard: Sequence[str] = (),
                          position_sigma_horizontal_m: float = 0.0,
                          position_sigma_vertical_m: float = 0.0, holding: bool = False,
                          deaf: Sequence[str] = (), broken: Sequence[str] = ()) -> None:
        """``/<id>/avoidance``: :meth:`Ros2Codec.avoidance_status` of these values."""
        self.avoidance.put(self.codec.avoidance_status(
            t_s, active, z_offset_m, yielding_to, heard=heard,
            position_sigma_horizontal_m=position_sigma_horizontal_m,
            position_sigma_vertical_m=position_sigma_vertical_m, holding=holding, deaf=deaf,
            broken=broken), round(t_s * 1e9))

    def missions(self, now_s: float, build: Callable[[np.ndarray | None, np.ndarray], M],
                 most: int = 4) -> tuple[list[M], list[str]]:
        """The missions that arrived, each made by ``build(times or None, points (n, 4))``
        (the caller's validation: it raises ValueError on a bad one); returns (missions,
        the reasons of those rejected)."""
        out: list[M] = []
        rejected: list[str] = []
        for sub, kind in ((self.goal, "goal"), (self.trajectory, "trajectory")):
            if sub is None:
                continue
            for data in sub.drain(most):
                try:
                    if kind == "goal":
                        p, heading = self.codec.goal(data)
                        out.append(build(None, np.array([[*p, heading]])))
                    else:
                        out.append(build(*self.codec.trajectory(data)))
                except (ValueError, TypeError) as exc:
                    rejected.append(f"{kind}: {exc}")
        return out, rejected

    def close(self) -> None:
        pass  # the graph owns the entities

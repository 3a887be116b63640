"""uavmpc on a ROS 2 graph over DDS, as a default ROS 2 install (Fast DDS, Cyclone DDS) sees it.

The same node, topics, message types and QoS as :mod:`uavmpc.comms.ros2` (rmw_zenoh), spoken
with Eclipse Cyclone DDS (``cyclonedds`` on PyPI, optional extra ``uavmpc[ros2]``) the way
ROS 2's DDS middlewares write them:

- **topics**: ROS topic ``/uav1/pose`` is the DDS topic ``rt/uav1/pose``; its type name is
  ``geometry_msgs::msg::dds_::PoseStamped_``; the payload is the same CDR (XCDR1, with its
  encapsulation header) the Zenoh path puts, written as is;
- **QoS**: reliable, volatile, keep last 10, and in each writer's and reader's USER_DATA
  ``typehash=RIHS01_<hash>;`` (REP 2011: how rmw_fastrtps and rmw_cyclonedds advertise the type
  hash that ``ros2 topic info -v`` shows);
- **graph**: one participant per :class:`DdsGraph`, announcing its one ROS node on
  ``ros_discovery_info`` (``rmw_dds_common/msg/ParticipantEntitiesInfo``: the participant's
  GUID, and for the node its namespace, name and its readers' and writers' GUIDs; reliable,
  transient local, keep last 1), so that ``ros2 node list`` names it.

Discovery is DDS's own (SPDP multicast on the domain's port); ``ROS_DOMAIN_ID`` picks the
domain. Cyclone's defaults apply, including ``CYCLONEDDS_URI`` for a site's configuration.

The DDS data types are built from the same rosbags type store the codec uses (one definition
of each message), and carry the CDR bytes through unchanged: what is written is what the codec
encoded, what a reader hands on is what arrived, decoded (and refused if bad) by the codec.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Self

import numpy as np
import numpy.typing as npt

from uavmpc.comms.ros2 import (
    QOS_KEEP_LAST_10,
    Ros2Codec,
    Ros2Stats,
    _need,
    dds_type_name,
    graph_identity,
)

if TYPE_CHECKING:
    from cyclonedds.core import Qos
    from cyclonedds.domain import Domain
    from cyclonedds.idl import IdlStruct
    from cyclonedds.topic import Topic

    class _RawStruct(IdlStruct):
        """The shape of what :meth:`_DdsTypes.raw` makes at run time (make_idl_struct
        cannot say it): its samples hold their CDR, as written or as arrived."""

        cdr: bytes

        @classmethod
        def of(cls, cdr: bytes) -> Self: ...

__all__ = ["DdsGraph", "DdsPublisher", "DdsSubscriber", "dds_topic_name", "require", "user_data"]

DISCOVERY_TOPIC = "ros_discovery_info"
PARTICIPANT_INFO = "rmw_dds_common/msg/ParticipantEntitiesInfo"

def require() -> None:
    """Raise ImportError, naming the extra to install, unless Cyclone DDS imports."""
    _need("cyclonedds.domain")


def dds_topic_name(topic: str) -> str:
    """ROS topic → DDS topic: ``/uav1/pose`` → ``rt/uav1/pose``."""
    if not topic.startswith("/"):
        raise ValueError(f"topic: a fully qualified ROS name starts with '/', got {topic!r}")
    return "rt" + topic


def user_data(type_hash: str) -> bytes:
    """The USER_DATA of a ROS 2 writer or reader: ``typehash=RIHS01_…;``."""
    return f"typehash={type_hash};".encode()


#: Cyclone DDS's configuration of every domain we join: match Fast DDS's endpoints by type name,
#: as ROS 2 does, ignoring the XTypes type information Fast DDS 3 (ROS 2 Kilted) sends; Cyclone
#: cannot use it for ROS's types and would match none of them. eProsima's vendor id: 1.15.
COMPATIBILITY = ("<CycloneDDS><Domain><Compatibility><IgnoreTypeInformation>1.15"
                 "</IgnoreTypeInformation></Compatibility></Domain></CycloneDDS>")
_domains: dict[int, Domain] = {}


def _configure(domain_id: int) -> None:
    """Create the domain once per process with :data:`COMPATIBILITY`, then what
    ``CYCLONEDDS_URI`` adds (a site's configuration); the domain lives as long as the process."""
    if domain_id in _domains:
        return
    config = COMPATIBILITY
    if os.environ.get("CYCLONEDDS_URI"):
        config += "," + os.environ["CYCLONEDDS_URI"]
    _domains[domain_id] = _need("cyclonedds.domain").Domain(domain_id, config)


class _DdsTypes:
    """Cyclone DDS data types of ROS message types, made from the rosbags type store's fields.

    Each type is a plain IDL struct (final, no keys), named as rosidl names it for DDS. Its
    ``serialize`` hands back the CDR it was made with and its ``deserialize`` the bytes that
    arrived, so the codec stays the only encoder and decoder."""

    def __init__(self, codec: Ros2Codec) -> None:
        self.idl = _need("cyclonedds.idl")
        self.t = _need("cyclonedds.idl.types")
        self.fielddefs = codec.store.fielddefs
        self._made: dict[str, type[IdlStruct]] = {}
        self._raw: dict[str, type[_RawStruct]] = {}
        self._base = {"bool": bool, "float32": self.t.float32, "float64": self.t.float64,
                "int8": self.t.int8, "int16": self.t.int16, "int32": self.t.int32,
                "int64": self.t.int64, "uint8": self.t.uint8, "uint16": self.t.uint16,
                "uint32": self.t.uint32, "uint64": self.t.uint64,
                # rosidl: a message's byte is an IDL octet, its char an IDL uint8
                "byte": self.t.byte, "char": self.t.uint8, "octet": self.t.byte}

    def _field(self, node: tuple[object, Any]) -> object:
        """The IDL type of a rosbags field description ``(kind, arg)``."""
        # Any: the shape of ``arg`` depends on ``kind`` (rosbags' FieldDesc).
        kind, arg = node
        name = getattr(kind, "name", str(kind))
        if name == "BASE":
            type_name, bound = arg
            if type_name == "string":
                return self.t.bounded_str[bound] if bound else str
            return self._base[type_name]
        if name == "NAME":
            return self.struct(arg)
        inner, size = arg
        if name == "ARRAY":
            return self.t.array[self._field(inner), size]
        return self.t.sequence[self._field(inner), size] if size else \
            self.t.sequence[self._field(inner)]

    def struct(self, ros_type: str) -> type[IdlStruct]:
        """The IDL struct of ``ros_type`` (for nested fields)."""
        if ros_type not in self._made:
            _, fields = self.fielddefs[ros_type]
            self._made[ros_type] = self.idl.make_idl_struct(
                ros_type.replace("/", "_"), dds_type_name(ros_type),
                {name: self._field(node) for name, node in fields})
        return self._made[ros_type]

    def raw(self, ros_type: str) -> type[_RawStruct]:
        """The type a topic of ``ros_type`` is made with: ``raw(t).of(cdr)`` is a sample that
        writes ``cdr``; a reader's samples hold the CDR that arrived in ``.cdr``."""
        if ros_type not in self._raw:
            cls = self.idl.make_idl_struct(
                ros_type.replace("/", "_") + "_cdr", dds_type_name(ros_type),
                {name: self._field(node) for name, node in self.fielddefs[ros_type][1]})
            # set on the class, not mixed in: cyclonedds walks a struct's bases as IDL types
            cls.of = classmethod(_of)
            cls.serialize = _serialize
            cls.deserialize = classmethod(_deserialize)
            self._raw[ros_type] = cls
        return self._raw[ros_type]


def _of(cls: type[_RawStruct], cdr: bytes) -> _RawStruct:
    sample = object.__new__(cls)
    sample.cdr = cdr
    return sample


def _serialize(self: _RawStruct, *args: object, **kwargs: object) -> bytes:
    return bytes(self.cdr)


def _deserialize(cls: type[_RawStruct], data: bytes, *args: object,
                 **kwargs: object) -> _RawStruct:
    return _of(cls, bytes(data))


def _qos_of(qos: str, type_hash: str) -> Qos:
    """Cyclone QoS of an rmw_zenoh-style QoS field (we use reliable/volatile/keep-last-N)."""
    core = _need("cyclonedds.core")
    # rmw_zenoh's field: "<reliability>:<durability>:<history>,<depth>:…", empty = default
    kinds, depth = qos.split(",")[0:2]
    if kinds.strip(":"):
        raise ValueError(f"qos {qos!r}: uavmpc's topics are reliable, volatile, keep last")
    n = int(depth.split(":")[0] or 10)
    policy = core.Policy
    return core.Qos(policy.Reliability.Reliable(max_blocking_time=0),
                    policy.Durability.Volatile, policy.History.KeepLast(n),
                    policy.Userdata(user_data(type_hash)))


class DdsPublisher:
    """One ROS 2 publisher on DDS: ``put`` writes one CDR payload, stamped."""

    def __init__(self, graph: DdsGraph, topic: str, ros_type: str, qos: str) -> None:
        pub = _need("cyclonedds.pub")
        self.graph = graph
        self.topic = topic
        self.ros_type = ros_type
        self._type = graph.types.raw(ros_type)
        self._writer = pub.DataWriter(graph.participant, graph.dds_topic(topic, ros_type),
                                      _qos_of(qos, graph.codec.type_hash(ros_type)))
        self.gid = self._writer.guid.bytes

    def put(self, cdr: bytes, t_ns: int | None = None) -> None:
        """Publish one CDR payload. Its DDS source time stamp is the time of writing, as ROS 2's
        DDS middlewares stamp theirs (``t_ns``, the message's own time, is in its header)."""
        del t_ns
        self._writer.write(self._type.of(bytes(cdr)))
        self.graph.stats.published += 1
        self.graph.stats.bytes_published += len(cdr)

    def close(self) -> None:
        self._writer.__del__()  # cyclonedds has no close(): __del__ deletes, once


class DdsSubscriber:
    """One ROS 2 subscription on DDS: :meth:`drain` takes what arrived (at most ``maxlen``
    kept, the oldest dropped first), as CDR bytes for the codec."""

    def __init__(self, graph: DdsGraph, topic: str, ros_type: str, qos: str,
                 maxlen: int = 16) -> None:
        sub = _need("cyclonedds.sub")
        core = _need("cyclonedds.core")
        self.graph = graph
        self.topic = topic
        self.ros_type = ros_type
        q = _qos_of(qos, graph.codec.type_hash(ros_type))
        q += core.Qos(core.Policy.History.KeepLast(maxlen))
        self._reader = sub.DataReader(graph.participant, graph.dds_topic(topic, ros_type), q)
        self.gid = self._reader.guid.bytes

    def drain(self, most: int = 8) -> list[bytes]:
        cdr_type = self.graph.types.raw(self.ros_type)
        out = [s.cdr for s in self._reader.take(most)
               if isinstance(s, cdr_type)]  # else: an instance's state change, no data
        self.graph.stats.received += len(out)
        return out

    def close(self) -> None:
        self._reader.__del__()  # cyclonedds has no close(): __del__ deletes, once


class DdsGraph:
    """A DDS participant on a ROS 2 graph: one ROS node (``node_name`` in ``namespace``)
    whose publishers and subscribers appear in ``ros2 node list`` / ``ros2 topic list``; the
    same interface as :class:`uavmpc.comms.ros2.Ros2Graph`.

    Args:
        domain_id: ``ROS_DOMAIN_ID`` (default: that environment variable, else 0).
        node_name: the ROS node's name.
        namespace: the node's namespace ("/" for none).
    """

    def __init__(self, domain_id: int | None = None, *, node_name: str = "uavmpc",
                 namespace: str = "/") -> None:
        domain = _need("cyclonedds.domain")
        self.domain_id, self.node_name = graph_identity(domain_id, node_name)
        self.namespace = namespace
        self.codec = Ros2Codec()
        self.types = _DdsTypes(self.codec)
        self.stats = Ros2Stats()
        try:
            _configure(self.domain_id)
            self.participant = domain.DomainParticipant(self.domain_id)
        except Exception as exc:  # cyclonedds raises DDSException on a bad configuration
            raise OSError(f"cannot join DDS domain {self.domain_id}: {exc}") from None
        self.gid = self.participant.guid.bytes
        self._topics: dict[str, Topic[_RawStruct]] = {}
        self._entities: list[DdsPublisher | DdsSubscriber] = []
        pub = _need("cyclonedds.pub")
        core = _need("cyclonedds.core")
        policy = core.Policy
        info_hash = self.codec.type_hash(PARTICIPANT_INFO)
        self._info_writer = pub.DataWriter(
            self.participant, self.dds_topic(DISCOVERY_TOPIC, PARTICIPANT_INFO, ros=False),
            core.Qos(policy.Reliability.Reliable(max_blocking_time=0),
                     policy.Durability.TransientLocal, policy.History.KeepLast(1),
                     policy.Userdata(user_data(info_hash))))
        self._announce()

    def dds_topic(self, topic: str, ros_type: str, *,
                  ros: bool = True) -> Topic[_RawStruct]:
        name = dds_topic_name(topic) if ros else topic
        if name not in self._topics:
            self._topics[name] = _need("cyclonedds.topic").Topic(
                self.participant, name, self.types.raw(ros_type))
        return self._topics[name]

    def participant_info(self) -> bytes:
        """This participant's ParticipantEntitiesInfo (CDR): its GUID and its one node with
        the GUIDs of its readers and writers."""
        t = self.codec.types
        gid = t["rmw_dds_common/msg/Gid"]
        readers = [gid(data=_u8(e.gid)) for e in self._entities if isinstance(e, DdsSubscriber)]
        writers = [gid(data=_u8(e.gid)) for e in self._entities if isinstance(e, DdsPublisher)]
        node = t["rmw_dds_common/msg/NodeEntitiesInfo"](
            node_namespace=self.namespace, node_name=self.node_name,
            reader_gid_seq=readers, writer_gid_seq=writers)
        msg = t[PARTICIPANT_INFO](gid=gid(data=_u8(self.gid)), node_entities_info_seq=[node])
        return self.codec.encode(msg, PARTICIPANT_INFO)

    def _announce(self) -> None:
        self._info_writer.write(self.types.raw(PARTICIPANT_INFO).of(self.participant_info()))

    def publisher(self, topic: str, ros_type: str, qos: str = QOS_KEEP_LAST_10) -> DdsPublisher:
        pub = DdsPublisher(self, topic, ros_type, qos)
        self._entities.append(pub)
        self._announce()
        return pub

    def subscriber(self, topic: str, ros_type: str, qos: str = QOS_KEEP_LAST_10,
                   maxlen: int = 16) -> DdsSubscriber:
        sub = DdsSubscriber(self, topic, ros_type, qos, maxlen)
        self._entities.append(sub)
        self._announce()
        return sub

    def close(self) -> None:
        self._entities.clear()
        self._topics.clear()
        self.participant.__del__()  # deletes its readers, writers and topics with it

    def __enter__(self) -> DdsGraph:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _u8(data: bytes) -> npt.NDArray[np.uint8]:
    return np.frombuffer(data, dtype=np.uint8).copy()


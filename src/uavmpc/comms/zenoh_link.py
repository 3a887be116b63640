"""A real network transport over `Zenoh <https://zenoh.io>`_ (optional extra ``uavmpc[net]``).

:class:`ZenohTransport` implements :class:`~uavmpc.comms.link.Transport` for one UAV (one
process, one Zenoh peer session): ``publish`` puts the encoded prediction on the key
``uavmpc/<swarm>/<uav_id>/prediction``, best effort, dropped under congestion (a prediction is
superseded 0.5 s later anyway; retransmitting an old one only delays the new one);
``receive`` drains the predictions of the *other* UAVs that arrived since the last call.
Besides predictions, :meth:`ZenohTransport.put` and :meth:`ZenohTransport.subscribe` carry any
other topic (state, missions, ...) under ``uavmpc/<swarm>/``.

Bytes only: whatever arrives must still go through :class:`~uavmpc.comms.link.Inbox`, which
decodes, validates and (with a shared key, :mod:`uavmpc.comms.auth`) authenticates it.

Safe defaults
    Zenoh's own defaults listen on every interface and announce themselves by UDP multicast.
    Here nothing is opened that was not asked for: the session listens only on the ``listen``
    endpoints (none by default: it then only connects out), connects to the ``connect``
    endpoints and never uses multicast scouting. A chain of connections is enough: peers learn
    of each other by gossip over the links they have, and a peer forwards between two peers
    that cannot reach each other. Messages published in the first few hundred milliseconds,
    before the peers have met, are lost (best effort).

Bounded work per call
    Zenoh delivers samples on its own threads; the callbacks here only append to a bounded
    queue (O(1)). When a queue is full the *oldest* entry is dropped and counted, and
    ``receive`` hands out at most ``max_per_receive`` messages per call, so a flood of packets
    costs memory bounded by ``max_pending`` and cannot stall the caller's control loop.

TLS for real deployments
    Plain ``tcp/`` and ``udp/`` links are neither encrypted nor authenticated: anyone who can
    reach an endpoint can read and publish. Sign the messages (:mod:`uavmpc.comms.auth`) and, on
    any network that is not fully trusted, use Zenoh's TLS links: endpoints ``tls/host:port``
    and the certificates under the config keys ``transport/link/tls/``, passed as
    ``config_overrides`` (each value is a JSON5 literal: strings quoted)::

        tls = "transport/link/tls/"
        ZenohTransport(
            "uav1", swarm="alpha",
            listen=["tls/0.0.0.0:7447"], connect=["tls/gcs.example:7447"],
            config_overrides={
                tls + "root_ca_certificate": '"/etc/uavmpc/ca.pem"',
                tls + "listen_certificate": '"/etc/uavmpc/uav1.pem"',
                tls + "listen_private_key": '"/etc/uavmpc/uav1.key"',
                tls + "enable_mtls": "true",  # peers must show a certificate from the CA too
                tls + "connect_certificate": '"/etc/uavmpc/uav1.pem"',
                tls + "connect_private_key": '"/etc/uavmpc/uav1.key"',
                tls + "verify_name_on_connect": "true",  # the server name must match its cert
            })

    With ``enable_mtls`` both sides prove their identity with a certificate signed by the
    common CA (``root_ca_certificate``); ``verify_name_on_connect`` checks that the host
    connected to is the one named in its certificate. Any other Zenoh option can be set the
    same way (e.g. ``"scouting/gossip/enabled": "false"``); ``listen/endpoints`` and
    ``connect/endpoints`` are set only through ``listen`` and ``connect`` (they are
    validated).
"""

from __future__ import annotations

import json
import re
import threading
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Generic, Protocol, TypeVar

from uavmpc.comms.message import MAX_MESSAGE_BYTES

try:
    import zenoh
except ImportError:  # pragma: no cover - exercised only without the extra
    zenoh = None  # type: ignore[assignment]  # the optional import's stand-in, checked before use

__all__ = ["Subscription", "ZenohStats", "ZenohTransport"]

#: Root of every key expression.
PREFIX = "uavmpc"
PREDICTION_TOPIC = "prediction"
#: Largest prediction accepted into the queue: a maximal message plus a signature trailer.
MAX_PREDICTION_BYTES = MAX_MESSAGE_BYTES + 64
#: Default bound on a generic subscription's payloads (bytes).
DEFAULT_MAX_PAYLOAD = 64 * 1024

_NAME_RE = re.compile(r"[A-Za-z0-9_-]{1,32}")
_ENDPOINT_RE = re.compile(
    r"(?P<proto>tcp|udp|tls)/(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):(?P<port>\d{1,5})"
    r"(?P<rest>[?#]\S*)?")
_RESERVED_KEYS = ("listen/endpoints", "connect/endpoints", "listen", "connect")

_Item = TypeVar("_Item")


@dataclass
class ZenohStats:
    """Counters of a :class:`ZenohTransport` (predictions only).

    Attributes:
        published: predictions put on the network.
        received: predictions of other UAVs that arrived and were queued.
        delivered: predictions handed out by ``receive``.
        dropped_overflow: queued predictions dropped because the queue was full (the oldest go).
        dropped_oversize: arrivals larger than any valid (signed) prediction, never queued.
    """

    published: int = 0
    received: int = 0
    delivered: int = 0
    dropped_overflow: int = 0
    dropped_oversize: int = 0

    @property
    def pending(self) -> int:
        """Queued and not yet handed out."""
        return self.received - self.delivered - self.dropped_overflow


class _BoundedQueue(Generic[_Item]):
    """A thread-safe FIFO of bounded length; when full, the oldest entry is dropped."""

    def __init__(self, maxlen: int) -> None:
        self._items: deque[_Item] = deque()
        self._maxlen = maxlen
        self._lock = threading.Lock()
        self.dropped = 0

    def push(self, item: _Item) -> None:
        with self._lock:
            if len(self._items) >= self._maxlen:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)

    def pop(self, limit: int | None) -> list[_Item]:
        with self._lock:
            n = len(self._items) if limit is None else min(limit, len(self._items))
            return [self._items.popleft() for _ in range(n)]

    def __len__(self) -> int:
        return len(self._items)


class Subscription:
    """Samples of one key expression, queued for :meth:`drain` (made by
    :meth:`ZenohTransport.subscribe`).

    Attributes:
        keyexpr: the full key expression subscribed to.
        dropped: samples dropped because the queue was full (the oldest go).
        dropped_oversize: samples larger than ``max_payload``, never queued.
    """

    def __init__(self, keyexpr: str, maxlen: int, max_payload: int) -> None:
        self.keyexpr = keyexpr
        self.max_payload = max_payload
        self.dropped_oversize = 0
        self._queue: _BoundedQueue[tuple[str, bytes]] = _BoundedQueue(maxlen)
        self._subscriber: zenoh.Subscriber[None] | None = None

    @property
    def dropped(self) -> int:
        return self._queue.dropped

    @property
    def pending(self) -> int:
        return len(self._queue)

    def drain(self, limit: int | None = None) -> list[tuple[str, bytes]]:
        """Up to ``limit`` (all if ``None``) queued ``(key, payload)`` pairs, oldest first."""
        if limit is not None and limit < 0:
            raise ValueError(f"limit: must be ≥ 0 or None, got {limit}")
        return self._queue.pop(limit)

    def close(self) -> None:
        """Stop receiving (idempotent); what is queued can still be drained."""
        sub, self._subscriber = self._subscriber, None
        if sub is not None:
            try:
                sub.undeclare()
            except Exception:  # the session may already be closed
                pass

    def _on_sample(self, sample: zenoh.Sample) -> None:  # zenoh thread: O(1), never raises
        try:
            if sample.kind != zenoh.SampleKind.PUT:
                return
            payload = sample.payload.to_bytes()
            if len(payload) > self.max_payload:
                with self._queue._lock:
                    self.dropped_oversize += 1
                return
            self._queue.push((str(sample.key_expr), payload))
        except Exception:  # a bad sample must not kill zenoh's thread
            pass


class ZenohTransport:
    """One UAV's :class:`~uavmpc.comms.link.Transport` over a Zenoh peer session.

    Args:
        own_id: this UAV's id (1–32 characters of ``[A-Za-z0-9_-]``); ``publish`` and
            ``receive`` are only for this id.
        swarm: name of the swarm (same charset); only UAVs of the same swarm hear each other.
        listen: endpoints to accept connections on, e.g. ``"tcp/192.168.1.10:7447"``
            (``tcp/``, ``udp/`` or ``tls/``; ``host:port``; port 0 picks a free port). None by
            default: the session then only connects out.
        connect: endpoints of peers to connect to (retried by Zenoh until they appear).
        max_pending: predictions queued at most; beyond, the oldest are dropped and counted.
        max_per_receive: predictions handed out per ``receive`` call at most; the rest wait.
        config_overrides: extra Zenoh config ``{key: json5 value}`` applied last (see the
            module docstring for TLS).

    Raises:
        ValueError: a bad id, swarm name, endpoint, bound or config override (the text names it).
        OSError: Zenoh could not open the session (e.g. a listen port in use).
        ImportError: Zenoh is not installed (``pip install 'uavmpc[net]'``).

    ``close()`` releases the session (idempotent; also on leaving a ``with`` block).
    """

    def __init__(self, own_id: str, *, swarm: str = "default", listen: Sequence[str] = (),
                 connect: Sequence[str] = (), max_pending: int = 256, max_per_receive: int = 64,
                 config_overrides: Mapping[str, str] | None = None) -> None:
        _check_name(own_id, "own_id")
        _check_name(swarm, "swarm")
        listen_eps = check_endpoints(listen, "listen")
        connect_eps = check_endpoints(connect, "connect")
        _check_bound(max_pending, "max_pending")
        _check_bound(max_per_receive, "max_per_receive")
        if zenoh is None:
            raise ImportError(
                "ZenohTransport needs eclipse-zenoh: pip install 'uavmpc[net]'")
        self.own_id = own_id
        self.swarm = swarm
        self.listen = listen_eps
        self.connect = connect_eps
        self.max_pending = int(max_pending)
        self.max_per_receive = int(max_per_receive)
        self.stats = ZenohStats()
        self._predictions: _BoundedQueue[bytes] = _BoundedQueue(self.max_pending)
        self._subscriptions: list[Subscription] = []
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._lock = threading.Lock()
        self._closed = False

        config = _config(listen_eps, connect_eps, config_overrides or {})
        try:
            self._session = zenoh.open(config)
        except zenoh.ZError as exc:
            raise OSError(f"zenoh: could not open the session ({exc})") from None
        try:
            self._prediction_pub = self._session.declare_publisher(
                self._key(own_id, PREDICTION_TOPIC),
                congestion_control=zenoh.CongestionControl.DROP,
                reliability=zenoh.Reliability.BEST_EFFORT)
            self._prediction_sub = self._session.declare_subscriber(
                self._key("*", PREDICTION_TOPIC), self._on_prediction,
                allowed_origin=zenoh.Locality.REMOTE)
        except BaseException:
            self._session.close()
            raise

    # ------------------------------------------------------------------------ Transport
    def publish(self, msg_bytes: bytes, sender_id: str, t_s: float) -> None:
        """Put ``msg_bytes`` on this UAV's prediction key (``t_s`` is unused: the network runs
        on wall-clock time)."""
        if not isinstance(msg_bytes, bytes | bytearray):
            raise TypeError(f"msg_bytes: expected bytes, got {type(msg_bytes).__name__}")
        self._check_own(sender_id, "sender_id")
        self._check_open()
        self._prediction_pub.put(bytes(msg_bytes))
        self.stats.published += 1

    def receive(self, receiver_id: str, t_s: float) -> list[bytes]:
        """At most ``max_per_receive`` predictions of other UAVs, oldest arrival first."""
        self._check_own(receiver_id, "receiver_id")
        with self._lock:
            out = self._predictions.pop(self.max_per_receive)
            self.stats.delivered += len(out)
        return out

    # ------------------------------------------------------------------------ generic topics
    def put(self, topic: str, payload: bytes) -> None:
        """Put ``payload`` on ``uavmpc/<swarm>/<own_id>/<topic>`` (best effort).

        ``topic`` is one or more ``/``-separated names of ``[A-Za-z0-9_-]`` (no wildcards).
        """
        self.send(self.own_id, topic, payload)

    def send(self, uav_id: str, topic: str, payload: bytes) -> None:
        """Put ``payload`` on another UAV's ``uavmpc/<swarm>/<uav_id>/<topic>`` (e.g. a ground
        station sending a mission to ``<uav_id>/mission``); best effort."""
        _check_name(uav_id, "uav_id")
        _check_topic(topic)
        if not isinstance(payload, bytes | bytearray):
            raise TypeError(f"payload: expected bytes, got {type(payload).__name__}")
        self._check_open()
        key = self._key(uav_id, topic)
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.DROP,
                reliability=zenoh.Reliability.BEST_EFFORT)
            self._publishers[key] = pub
        pub.put(bytes(payload))

    def subscribe(self, keyexpr_suffix: str, maxlen: int = 1024, *,
                  max_payload: int = DEFAULT_MAX_PAYLOAD,
                  include_own: bool = False) -> Subscription:
        """Queue the samples on ``uavmpc/<swarm>/<keyexpr_suffix>``.

        Args:
            keyexpr_suffix: ``/``-separated names of ``[A-Za-z0-9_-]``, or ``*`` (one chunk)
                or ``**`` (any number of chunks), e.g. ``"*/state"``, ``"uav1/mission"``,
                ``"**"``.
            maxlen: samples queued at most; beyond, the oldest are dropped and counted.
            max_payload: larger samples are dropped (counted in ``dropped_oversize``).
            include_own: also deliver what this transport itself puts.

        A new subscription takes a moment (a round trip or so) to become known to the
        publishers; what they put before that does not reach it.
        """
        _check_suffix(keyexpr_suffix)
        _check_bound(maxlen, "maxlen")
        _check_bound(max_payload, "max_payload")
        self._check_open()
        key = f"{PREFIX}/{self.swarm}/{keyexpr_suffix}"
        sub = Subscription(key, int(maxlen), int(max_payload))
        origin = zenoh.Locality.ANY if include_own else zenoh.Locality.REMOTE
        sub._subscriber = self._session.declare_subscriber(key, sub._on_sample,
                                                           allowed_origin=origin)
        self._subscriptions.append(sub)
        return sub

    # ------------------------------------------------------------------------ lifecycle
    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Close the session (idempotent). Queued messages can still be received/drained."""
        if self._closed:
            return
        self._closed = True
        for sub in self._subscriptions:
            sub._subscriber = None  # undeclared with the session
        try:
            self._session.close()
        except Exception:  # closing twice from Zenoh's side is harmless
            pass

    def __enter__(self) -> ZenohTransport:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return (f"ZenohTransport({self.own_id!r}, swarm={self.swarm!r}, listen={self.listen}, "
                f"connect={self.connect}, {state})")

    # ------------------------------------------------------------------------ internals
    def _key(self, uav_id: str, topic: str) -> str:
        return f"{PREFIX}/{self.swarm}/{uav_id}/{topic}"

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"ZenohTransport {self.own_id!r} is closed")

    def _check_own(self, uav_id: str, name: str) -> None:
        if uav_id != self.own_id:
            raise ValueError(
                f"{name}: this transport belongs to {self.own_id!r}, got {uav_id!r}")

    def _on_prediction(self, sample: zenoh.Sample) -> None:  # zenoh thread: O(1), never raises
        try:
            if sample.kind != zenoh.SampleKind.PUT:
                return
            # uavmpc/<swarm>/<sender>/prediction: skip another session using our own id.
            if str(sample.key_expr).split("/", 3)[2] == self.own_id:
                return
            payload = sample.payload.to_bytes()
            with self._lock:
                if len(payload) > MAX_PREDICTION_BYTES:
                    self.stats.dropped_oversize += 1
                    return
                self._predictions.push(payload)
                self.stats.received += 1
                self.stats.dropped_overflow = self._predictions.dropped
        except Exception:  # a bad sample must not kill zenoh's thread
            pass


# ---------------------------------------------------------------------------- validation
def _check_name(value: object, name: str) -> None:
    if not isinstance(value, str) or _NAME_RE.fullmatch(value) is None:
        raise ValueError(f"{name}: must be 1–32 characters of [A-Za-z0-9_-], got {value!r}")


def _check_bound(value: object, name: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name}: must be an integer ≥ 1, got {value!r}")


def check_endpoints(endpoints: Sequence[str], name: str) -> list[str]:
    if isinstance(endpoints, str | bytes):
        raise ValueError(f"{name}: expected a sequence of endpoints, got the string "
                         f"{endpoints!r} (wrap it in a list)")
    out = []
    for ep in endpoints:
        if not isinstance(ep, str):
            raise ValueError(f"{name}: endpoint must be a string, got {ep!r}")
        m = _ENDPOINT_RE.fullmatch(ep)
        if m is None:
            if not ep.startswith(("tcp/", "udp/", "tls/")):
                raise ValueError(
                    f"{name}: endpoint {ep!r} must start with tcp/, udp/ or tls/")
            raise ValueError(f"{name}: endpoint {ep!r} must be <proto>/<host>:<port>")
        if int(m["port"]) > 65535:
            raise ValueError(f"{name}: endpoint {ep!r} has a port beyond 65535")
        out.append(ep)
    return out


def _check_topic(topic: object) -> None:
    if not isinstance(topic, str) or not topic or not all(
            _NAME_RE.fullmatch(chunk) for chunk in topic.split("/")):
        raise ValueError(
            f"topic: must be '/'-separated names of [A-Za-z0-9_-] (1–32 characters each), "
            f"got {topic!r}")


def _check_suffix(suffix: object) -> None:
    if not isinstance(suffix, str) or not suffix or not all(
            chunk in ("*", "**") or _NAME_RE.fullmatch(chunk) for chunk in suffix.split("/")):
        raise ValueError(
            f"keyexpr_suffix: must be '/'-separated names of [A-Za-z0-9_-], '*' or '**', "
            f"got {suffix!r}")


class Router(Protocol):
    """A Zenoh router's session, as its owner uses it (zenoh's own ``close`` is untyped)."""

    def close(self) -> None: ...


def loopback_router(port: int) -> Router:
    """A Zenoh router listening on ``tcp/127.0.0.1:<port>`` only, without multicast scouting
    (a stand-in for ROS 2's ``rmw_zenohd`` in benchmarks and tests); close it when done."""
    config = _config([f"tcp/127.0.0.1:{int(port)}"], [], {})
    config.insert_json5("mode", '"router"')
    return zenoh.open(config)


def _config(listen: list[str], connect: list[str],
            overrides: Mapping[str, str]) -> zenoh.Config:
    config = zenoh.Config()
    base = {
        "mode": '"peer"',
        "listen/endpoints": json.dumps(listen),
        "connect/endpoints": json.dumps(connect),
        "scouting/multicast/enabled": "false",
    }
    for key, value in base.items():
        config.insert_json5(key, value)
    if not isinstance(overrides, Mapping):
        raise ValueError(f"config_overrides: expected a mapping, got {type(overrides).__name__}")
    for key, value in overrides.items():
        if not isinstance(key, str) or not isinstance(value, str):
            raise ValueError(
                f"config_overrides: keys and values must be strings (values JSON5 literals), "
                f"got {key!r}: {value!r}")
        if key.strip("/") in _RESERVED_KEYS:
            raise ValueError(
                f"config_overrides[{key!r}]: set endpoints with listen=/connect= (validated)")
        try:
            config.insert_json5(key, value)
        except zenoh.ZError as exc:
            raise ValueError(f"config_overrides[{key!r}]: rejected by zenoh ({exc})") from None
    return config

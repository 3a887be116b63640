"""The prediction message every UAV broadcasts at 2 Hz (SPEC §5.1), and its wire format.

The link is lossy, unconfirmed and shared with whatever else is on the air, so a receiver must
assume any byte string can arrive. :func:`decode` therefore either returns a fully valid
:class:`PredictionMessage` or raises :class:`InvalidMessageError` naming the problem; it never
raises anything else (a fuzz test holds it to that).

Wire format (version 2), all little-endian, no padding::

    offset  size        field
    0       4           magic b"UAVP"
    4       1           version (uint8, = 2)
    5       1           flags (uint8; bit 0 = avoiding, other bits must be 0)
    6       1           id length n (uint8, 1..32)
    7       2           m, number of prediction points (uint16, 2..200)
    9       4           priority (int32; lower number = higher priority)
    13      8           stamp_s (float64, absolute send time)
    21      n           uav_id, ASCII [A-Za-z0-9_-]
    21+n    8 m         times_s (float64)
    21+n+8m 24 m        positions_m (float64, row-major (m, 3), ENU)
    21+n+32m 16         position_sigma_m (float64 × 2: horizontal, vertical 1σ [m])
    37+n+32m 1          h, number of UAVs heard (uint8, 0..64)
    ...     h × (1 + k) each: id length k (uint8, 1..32), then the id, ASCII

float64 throughout keeps the round trip bit-exact and absolute stamps (≈1.7e9 s of GNSS/Unix
time) at µs resolution. A 40-point message that heard nobody is 38 + n + 1280 bytes.

Version 2 added two things (docs/safety.md):

- the **position uncertainty** of the sender: how far its own estimate of where it is may be
  from where it is (1σ per horizontal axis and vertically, from its estimator; 0 for a true
  state or a centimetre-class fix). Receivers widen the pair's cylinder by both UAVs' (A3);
- the **heard list**: the UAVs whose plans the sender counts (fresh, or silent at their last
  plan), near or not — at most :data:`MAX_HEARD`, the nearest first beyond that. A peer near
  us that does not list us has not heard us, and will not make way for us (A2).

A version-1 message is refused by name (``unsupported schema version 1``), as a version-1 stack
refuses ours: an old and a new stack never read each other silently wrong.
"""

from __future__ import annotations

import functools
import math
import re
import struct
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from uavmpc.jit import kernel

#: The schema version this code writes and the only one it reads.
SCHEMA_VERSION = 2
MAGIC = b"UAVP"
#: Bounds on the number of prediction points (our tracker sends 40).
MIN_POINTS = 2
MAX_POINTS = 200
#: Positions farther than this from the origin (per axis) are a unit or frame bug, not a UAV.
MAX_ABS_POSITION_M = 1.0e5
MAX_ID_LEN = 32
#: The largest position uncertainty a message may state (1σ) [m]: beyond it, no cylinder means
#: anything.
MAX_SIGMA_M = 100.0
#: At most this many UAVs in a message's heard list (beyond it, the nearest to its sender).
MAX_HEARD = 64
#: Priorities travel as int32.
PRIORITY_RANGE = (-(2**31), 2**31 - 1)

_HEADER = struct.Struct("<4sBBBHid")
_SIGMA = struct.Struct("<dd")
_FLAG_AVOIDING = 0x01
#: An id in a heard list: its length (uint8), then up to :data:`MAX_ID_LEN` ASCII characters.
ENTRY_BYTES = 1 + MAX_ID_LEN
_MAGIC_BYTES = np.frombuffer(MAGIC, dtype=np.uint8)
_ID_RE = re.compile(r"[A-Za-z0-9_-]{1,32}")
# A non-empty heard list joined by NUL, checked in one match (a 300-UAV world checks 80 000
# ids a second): with exactly len - 1 NULs in it (none inside an id), it matches exactly when
# every id does.
_IDS_RE = re.compile(r"[A-Za-z0-9_-]{1,32}(?:\x00[A-Za-z0-9_-]{1,32})*")
_F64 = np.dtype("<f8")
#: Largest valid message: anything longer is rejected before any parsing work.
MAX_MESSAGE_BYTES = _HEADER.size + MAX_ID_LEN + 32 * MAX_POINTS + 16 + 1 + MAX_HEARD * (
    1 + MAX_ID_LEN)


class InvalidMessageError(ValueError):
    """Bytes or fields that do not form a usable prediction message (the text names why)."""


@dataclass(frozen=True, eq=False)
class PredictionMessage:
    """One UAV's broadcast prediction (SPEC §5.1). Construction validates every field.

    Attributes:
        version: schema version (:data:`SCHEMA_VERSION`).
        uav_id: sender id, 1–32 characters of ``[A-Za-z0-9_-]``.
        priority: unique integer; a LOWER number means a HIGHER priority.
        stamp_s: absolute time the message was sent (s, sender's clock).
        times_s: (m,) absolute times of the prediction points, strictly increasing (s).
        positions_m: (m, 3) predicted positions, ENU world frame (m).
        avoiding: this UAV runs collision avoidance and will yield to higher priorities. A UAV
            whose flag is down is non-cooperative, or stuck (it stands where one it yields to
            will pass and cannot move out of the way): everyone yields to it.
        received_s: local metadata, never sent: the receiver's clock when the message arrived
            (set by the receiving inbox; used by the receive-time fallback for unsynchronised
            clocks). ``None`` when unknown.
        position_sigma_m: (horizontal, vertical) 1σ of the sender's own position estimate
            [m], each in [0, :data:`MAX_SIGMA_M`].
        heard: the UAVs whose plans the sender counts, fresh or silent, near or not (at
            most :data:`MAX_HEARD`, distinct, not the sender): a UAV near it that is not
            listed has not been heard by it (docs/safety.md).

    Arrays are stored as read-only float64 copies, so a message cannot change after validation.
    """

    version: int
    uav_id: str
    priority: int
    stamp_s: float
    times_s: np.ndarray
    positions_m: np.ndarray
    avoiding: bool
    received_s: float | None = None
    heard: tuple[str, ...] = ()
    position_sigma_m: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if isinstance(self.version, bool) or not isinstance(self.version, int):
            raise InvalidMessageError(f"version: must be an integer, got {self.version!r}")
        if self.version != SCHEMA_VERSION:
            raise InvalidMessageError(
                f"version: unsupported schema version {self.version} (expected {SCHEMA_VERSION})")
        _check_id(self.uav_id)
        if isinstance(self.priority, bool) or not isinstance(self.priority, int | np.integer):
            raise InvalidMessageError(f"priority: must be an integer, got {self.priority!r}")
        if not PRIORITY_RANGE[0] <= int(self.priority) <= PRIORITY_RANGE[1]:
            raise InvalidMessageError(f"priority: {self.priority} does not fit in int32")
        object.__setattr__(self, "priority", int(self.priority))
        object.__setattr__(self, "stamp_s", _finite(self.stamp_s, "stamp_s"))
        if self.received_s is not None:
            object.__setattr__(self, "received_s", _finite(self.received_s, "received_s"))
        if not isinstance(self.avoiding, bool | np.bool_):
            raise InvalidMessageError(f"avoiding: must be a bool, got {self.avoiding!r}")
        object.__setattr__(self, "avoiding", bool(self.avoiding))
        object.__setattr__(self, "heard", _check_heard(self.heard, self.uav_id))
        object.__setattr__(self, "position_sigma_m", _check_sigma(self.position_sigma_m))
        times = _float_array(self.times_s, "times_s")
        pos = _float_array(self.positions_m, "positions_m")
        _check_arrays(times, pos)
        object.__setattr__(self, "times_s", times)
        object.__setattr__(self, "positions_m", pos)

    @property
    def points(self) -> int:
        """m, the number of prediction points."""
        return int(self.times_s.shape[0])


class Planned(Protocol):
    """What a message takes of a tracker's plan: where, not how."""

    @property
    def times_s(self) -> np.ndarray: ...

    @property
    def position_m(self) -> np.ndarray: ...


def from_prediction(prediction: Planned, *, uav_id: str, priority: int, stamp_s: float,
                    avoiding: bool = True, heard: tuple[str, ...] = (),
                    position_sigma_m: tuple[float, float] = (0.0, 0.0)) -> PredictionMessage:
    """A message from a tracker :class:`~uavmpc.tracker.Prediction` (uses ``times_s`` and
    ``position_m`` only: others need where, not how)."""
    return PredictionMessage(SCHEMA_VERSION, uav_id, priority, stamp_s,
                             prediction.times_s, prediction.position_m, avoiding, heard=heard,
                             position_sigma_m=position_sigma_m)


def encode(msg: PredictionMessage) -> bytes:
    """The wire bytes of ``msg`` (see the module docstring). ``received_s`` is not sent."""
    entries = np.frombuffer(b"".join(map(id_entry, (msg.uav_id, *msg.heard))),
                            dtype=np.uint8).reshape(-1, ENTRY_BYTES)
    out = np.empty(MAX_MESSAGE_BYTES, dtype=np.uint8)
    n = write_message(out, entries[0], msg.avoiding, msg.priority,
                      np.array([msg.stamp_s, *msg.position_sigma_m]), msg.times_s,
                      msg.positions_m, entries, _HEARD_ROWS[:len(msg.heard)])
    return out[:n].tobytes()


#: Rows 1… of an ``encode`` call's entries: its heard ids, in order.
_HEARD_ROWS = np.arange(1, MAX_HEARD + 1, dtype=np.int64)


@functools.lru_cache(maxsize=4096)
def id_entry(uav_id: str) -> bytes:
    """An id as the wire writes it, padded to :data:`ENTRY_BYTES`: its length byte, the id
    in ASCII, zeros (a world's UAVs list the same few hundred ids in every message: kept, not
    built again). Only for an id :func:`valid_id` accepts."""
    raw = uav_id.encode("ascii")
    return bytes((len(raw),)) + raw + bytes(ENTRY_BYTES - 1 - len(raw))


def valid_id(uav_id: object) -> bool:
    """``uav_id`` may name a UAV in a message: 1–32 characters of ``[A-Za-z0-9_-]``."""
    return isinstance(uav_id, str) and _ID_RE.fullmatch(uav_id) is not None


@kernel
def _copy_bytes(out: np.ndarray, at: int, src: np.ndarray) -> int:
    for k in range(src.shape[0]):
        out[at + k] = src[k]
    return at + src.shape[0]


@kernel
def write_message(out: np.ndarray, uid: np.ndarray, avoiding: bool, priority: int,
                  floats: np.ndarray, times: np.ndarray, pos: np.ndarray, entries: np.ndarray,
                  heard: np.ndarray) -> int:
    """The wire format, written once: the bytes of a message into ``out`` (uint8, at least
    :data:`MAX_MESSAGE_BYTES`); returns their length. ``uid`` (:data:`ENTRY_BYTES`,) the
    sender's :func:`id_entry`; ``floats`` (3,) [stamp_s, σ horizontal, σ vertical];
    ``times`` (m,) and ``pos`` (m, 3) C-contiguous float64; the heard list is rows
    ``heard`` (h,) of ``entries`` (K, :data:`ENTRY_BYTES`). The fields must be valid
    (:class:`PredictionMessage` checks them): nothing is checked here. Float64 are written in
    the machine's byte order, little-endian on every platform numba targets."""
    m = times.shape[0]
    for k in range(4):
        out[k] = _MAGIC_BYTES[k]
    out[4] = SCHEMA_VERSION
    out[5] = _FLAG_AVOIDING if avoiding else 0
    n = uid[0]
    out[6] = n
    out[7] = m & 0xFF
    out[8] = (m >> 8) & 0xFF
    word = priority & 0xFFFFFFFF  # two's complement int32
    for k in range(4):
        out[9 + k] = (word >> (8 * k)) & 0xFF
    fb = floats.view(np.uint8)
    at = _copy_bytes(out, 13, fb[0:8])
    at = _copy_bytes(out, at, uid[1:1 + n])
    at = _copy_bytes(out, at, times.view(np.uint8))
    at = _copy_bytes(out, at, pos.reshape(3 * m).view(np.uint8))
    at = _copy_bytes(out, at, fb[8:24])
    out[at] = heard.shape[0]
    at += 1
    for j in range(heard.shape[0]):
        e = entries[heard[j]]
        at = _copy_bytes(out, at, e[0:e[0] + 1])
    return at


def decode(data: bytes) -> PredictionMessage:
    """Parse and validate wire bytes; raises :class:`InvalidMessageError` naming the problem."""
    if not isinstance(data, bytes | bytearray | memoryview):
        raise InvalidMessageError(f"data: expected bytes, got {type(data).__name__}")
    data = bytes(data)
    if len(data) < _HEADER.size:
        raise InvalidMessageError(
            f"truncated: {len(data)} bytes, shorter than the {_HEADER.size}-byte header")
    if len(data) > MAX_MESSAGE_BYTES:
        raise InvalidMessageError(
            f"oversized: {len(data)} bytes, more than the {MAX_MESSAGE_BYTES}-byte maximum")
    magic, version, flags, id_len, m, priority, stamp = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise InvalidMessageError(f"magic: expected {MAGIC!r}, got {magic!r}")
    if version != SCHEMA_VERSION:
        raise InvalidMessageError(
            f"version: unsupported schema version {version} (expected {SCHEMA_VERSION})")
    if flags & ~_FLAG_AVOIDING:
        raise InvalidMessageError(f"flags: unknown bits set in 0x{flags:02x}")
    if not 1 <= id_len <= MAX_ID_LEN:
        raise InvalidMessageError(f"uav_id: length {id_len} outside [1, {MAX_ID_LEN}]")
    if not MIN_POINTS <= m <= MAX_POINTS:
        raise InvalidMessageError(f"points: m={m} outside [{MIN_POINTS}, {MAX_POINTS}]")
    expected = _HEADER.size + id_len + 32 * m + _SIGMA.size + 1
    if len(data) < expected:
        raise InvalidMessageError(
            f"truncated: {len(data)} bytes, expected {expected} for m={m} and an id of {id_len}")
    start = _HEADER.size
    try:
        uav_id = data[start:start + id_len].decode("ascii")
    except UnicodeDecodeError:
        raise InvalidMessageError("uav_id: not ASCII") from None
    start += id_len
    times = np.frombuffer(data, dtype=_F64, count=m, offset=start)
    pos = np.frombuffer(data, dtype=_F64, count=3 * m, offset=start + 8 * m).reshape(m, 3)
    sigma = _SIGMA.unpack_from(data, start + 32 * m)
    heard = _decode_heard(data, start + 32 * m + _SIGMA.size)
    return PredictionMessage(version, uav_id, priority, stamp, times, pos,
                             bool(flags & _FLAG_AVOIDING), heard=heard, position_sigma_m=sigma)


def _decode_heard(data: bytes, start: int) -> tuple[str, ...]:
    """The heard list at ``start`` (its count byte), which must end the message exactly."""
    h = data[start]
    if h > MAX_HEARD:
        raise InvalidMessageError(f"heard: {h} UAVs, more than {MAX_HEARD}")
    at = start + 1
    out = []
    for i in range(h):
        if at >= len(data):
            raise InvalidMessageError(f"truncated: {len(data)} bytes, the heard list's entry "
                                      f"{i} is missing")
        k = data[at]
        if not 1 <= k <= MAX_ID_LEN or at + 1 + k > len(data):
            raise InvalidMessageError(f"heard[{i}]: id length {k} outside [1, {MAX_ID_LEN}] or "
                                      "past the end")
        try:
            out.append(data[at + 1:at + 1 + k].decode("ascii"))
        except UnicodeDecodeError:
            raise InvalidMessageError(f"heard[{i}]: not ASCII") from None
        at += 1 + k
    if at != len(data):
        raise InvalidMessageError(f"oversized: {len(data)} bytes, expected {at} (the heard "
                                  f"list of {h} ends there)")
    return tuple(out)


def validate_on_receipt(msg: PredictionMessage, now_s: float, max_future_s: float = 0.5,
                        max_age_s: float = 1.0) -> PredictionMessage:
    """Reject a message stamped in the future (beyond a clock tolerance) or too old to use.

    Only meaningful with synchronised clocks (SPEC §5.1: GNSS time); with the receive-time
    fallback the sender's stamps are on another clock and must not be checked against ``now_s``.

    Args:
        msg: a decoded message.
        now_s: the receiver's clock (s).
        max_future_s: allowed clock disagreement (s); stamps later than ``now_s + max_future_s``
            are rejected: they would otherwise win "newest per sender" forever.
        max_age_s: messages older than this (s) are rejected as stale (the avoidance timeout).

    Returns:
        ``msg`` unchanged, so that calls can be chained.
    """
    if not math.isfinite(now_s):
        raise ValueError(f"now_s: must be finite, got {now_s}")
    ahead = msg.stamp_s - now_s
    if ahead > max_future_s:
        raise InvalidMessageError(
            f"future-stamped: stamp_s={msg.stamp_s} is {ahead:.3f} s ahead of now_s={now_s} "
            f"(tolerance {max_future_s} s)")
    if -ahead > max_age_s:
        raise InvalidMessageError(
            f"stale: stamp_s={msg.stamp_s} is {-ahead:.3f} s old (max_age_s {max_age_s} s)")
    return msg


def _check_id(uav_id: object) -> None:
    if not valid_id(uav_id):
        raise InvalidMessageError(
            f"uav_id: must be 1–{MAX_ID_LEN} characters of [A-Za-z0-9_-], got {uav_id!r}")


def _check_sigma(sigma: Any) -> tuple[float, float]:
    # Any: whatever the caller gave, unpacked here and refused if it is not two numbers.
    try:
        h, v = sigma
    except (TypeError, ValueError):
        raise InvalidMessageError(f"position_sigma_m: must be (horizontal, vertical), got "
                                  f"{sigma!r}") from None
    out = (_finite(h, "position_sigma_m"), _finite(v, "position_sigma_m"))
    if not sigma_in_range(*out):
        raise InvalidMessageError(f"position_sigma_m: each must be in [0, {MAX_SIGMA_M:g}] m, "
                                  f"got {list(out)}")
    return out


def _check_heard(heard: object, sender: str) -> tuple[str, ...]:
    if isinstance(heard, str) or not isinstance(heard, tuple | list):
        raise InvalidMessageError(f"heard: must be a tuple of UAV ids, got {heard!r}")
    if len(heard) > MAX_HEARD:
        raise InvalidMessageError(f"heard: {len(heard)} UAVs, more than {MAX_HEARD}")
    try:
        joined = "\x00".join(heard)
        every_id_valid = not heard or (joined.count("\x00") == len(heard) - 1
                                       and _IDS_RE.fullmatch(joined) is not None)
    except TypeError:  # not all str
        every_id_valid = False
    if not every_id_valid:
        for h in heard:
            _check_id(h)  # raises naming the first bad one
    if len(set(heard)) != len(heard):
        raise InvalidMessageError(f"heard: an id listed twice in {list(heard)}")
    if sender in heard:
        raise InvalidMessageError(f"heard: the sender {sender!r} lists itself")
    return tuple(heard)


def _finite(value: object, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise InvalidMessageError(f"{field}: must be a number, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise InvalidMessageError(f"{field}: must be finite, got {out}")
    return out


def _float_array(value: object, field: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)  # a copy: the caller may reuse its buffer
    except (TypeError, ValueError):
        raise InvalidMessageError(f"{field}: not numeric") from None
    arr.flags.writeable = False
    return arr


def _check_arrays(times: np.ndarray, pos: np.ndarray) -> None:
    if times.ndim != 1:
        raise InvalidMessageError(f"times_s: must be 1-D, got shape {times.shape}")
    m = times.shape[0]
    if not MIN_POINTS <= m <= MAX_POINTS:
        raise InvalidMessageError(f"points: m={m} outside [{MIN_POINTS}, {MAX_POINTS}]")
    if pos.shape != (m, 3):
        raise InvalidMessageError(f"positions_m: must have shape ({m}, 3), got {pos.shape}")
    kind, i = first_problem(times, pos, MAX_ABS_POSITION_M)
    if kind == _NON_FINITE_TIME:
        raise InvalidMessageError(f"times_s[{i}]: non-finite value {times[i]}")
    if kind == _NON_FINITE_POSITION:
        raise InvalidMessageError(f"positions_m[{i}]: non-finite value {pos[i].tolist()}")
    if kind == _NOT_INCREASING:
        raise InvalidMessageError(
            f"times_s: must increase strictly, times_s[{i}]={times[i]} then "
            f"times_s[{i + 1}]={times[i + 1]}")
    if kind == _ABSURD_POSITION:
        raise InvalidMessageError(
            f"positions_m[{i}]: {pos[i].tolist()} beyond the absurd-position bound "
            f"{MAX_ABS_POSITION_M:g} m")


@kernel
def sigma_in_range(horizontal_m: float, vertical_m: float) -> bool:
    """A stated position uncertainty is usable: each 1σ in [0, :data:`MAX_SIGMA_M`] m
    (false for NaN)."""
    return 0.0 <= horizontal_m <= MAX_SIGMA_M and 0.0 <= vertical_m <= MAX_SIGMA_M


@kernel
def fields_valid(id_len: int, priority: int, stamp_s: float, sigma_h_m: float,
                 sigma_v_m: float, times: np.ndarray, pos: np.ndarray) -> bool:
    """Whether a message of these values passes every check of :class:`PredictionMessage`
    on them (an id of ``id_len`` valid characters: 0 for an invalid id; a heard list of
    distinct valid ids other than the sender's, which the caller guarantees): the gate a
    compiled writer of messages (:func:`~uavmpc.onboard.broadcast_rows`) passes before it
    writes one without building it, else it builds it the checked way, which names the
    problem. ``times`` (m,), ``pos`` (m, 3)."""
    m = times.shape[0]
    return (1 <= id_len <= MAX_ID_LEN and PRIORITY_RANGE[0] <= priority <= PRIORITY_RANGE[1]
            and math.isfinite(stamp_s) and math.isfinite(sigma_h_m)
            and math.isfinite(sigma_v_m) and sigma_in_range(sigma_h_m, sigma_v_m)
            and MIN_POINTS <= m <= MAX_POINTS and pos.shape[0] == m
            and first_problem(times, pos, MAX_ABS_POSITION_M)[0] == 0)


_NON_FINITE_TIME, _NON_FINITE_POSITION, _NOT_INCREASING, _ABSURD_POSITION = 1, 2, 3, 4


@kernel
def first_problem(times: np.ndarray, pos: np.ndarray, bound: float) -> tuple[int, int]:
    """The first problem of a message's arrays, in the order they are reported: (kind, index)
    or (0, 0). Every message received or sent passes here, so it is one pass, compiled."""
    m = times.shape[0]
    for i in range(m):
        if not math.isfinite(times[i]):
            return _NON_FINITE_TIME, i
    for i in range(m):
        for j in range(3):
            if not math.isfinite(pos[i, j]):
                return _NON_FINITE_POSITION, i
    for i in range(m - 1):
        if not times[i + 1] - times[i] > 0.0:
            return _NOT_INCREASING, i
    for i in range(m):
        for j in range(3):
            if abs(pos[i, j]) > bound:
                return _ABSURD_POSITION, i
    return 0, 0

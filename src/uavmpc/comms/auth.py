"""Optional shared-key authentication of messages (HMAC-SHA256).

A receiver that holds the swarm's key can tell a message from a member of the swarm from one
forged by anyone else on the link: a forged prediction crossing our path would otherwise make
us climb (a non-cooperative intruder), or a forged high-priority one pin us down.

Wire format: the message bytes, then a 36-byte trailer::

    message || b"UAVS" || HMAC-SHA256(key, b"uavmpc-auth-v1\\0" || message || b"UAVS")

(the full 32-byte tag). Senders sign ``sign(encode(msg), key)``; an
:class:`~uavmpc.comms.link.Inbox` given the key verifies before it decodes, and counts
``"unsigned message"`` and ``"forged message (bad signature)"`` rejections like any other.

Per-member identities (optional, ``pip install 'uavmpc[auth]'``): each UAV and each operator
(a ground station) holds its own Ed25519 private key, and every receiver holds the swarm's
**roster** of public keys (:class:`Roster`, a TOML file), so a member cannot speak as another:
a prediction must be signed by the UAV it claims to be from, a command by an operator. The
wire format of such a message (:func:`seal`)::

    message || b"UAVA" || scheme (1) || signer id || len(id) (1) || seq (8, LE) || tag

with ``tag`` = Ed25519 (64 bytes, scheme 2) or, in shared-key mode, HMAC-SHA256 (32 bytes,
scheme 1) over ``b"uavmpc-auth-v2\0" || channel || b"\0" || everything before the tag``.
The **channel** (``"prediction"``, ``"uav1/mission"``, ``"formation"``) is signed too, so a
mission for one UAV cannot be replayed to another.

Commands are never replayed: :class:`CommandGate` keeps the highest ``seq`` per signer and
refuses any message that is not newer (``"replayed message"``). A signer's sequence numbers
are its clock in µs, kept strictly increasing (:class:`CommandSigner`), so they survive a
restart of the sender. A receiver that restarts forgets them: give the gate ``max_skew_s`` to
bound that window by the commands' age. Predictions carry their stamp, and an inbox keeps only
a sender's newest, so a replayed prediction is never newer than what it holds.

What this does NOT do: encrypt (anyone on the link can read; use TLS, see
:mod:`uavmpc.comms.zenoh_link`); in shared-key mode, tell members apart (every holder of the
key can sign as any id: use identities for that).

Keys: at least :data:`MIN_KEY_BYTES` random bytes (``python -c "import secrets;
print(secrets.token_hex(32))" > swarm.key``), identities made by ``uavmpc keygen``; every key
file must be readable by its owner only (``chmod 600``, checked on POSIX systems); load them
with :func:`load_key` and :func:`load_identity`.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import re
import stat
import string
import time
import tomllib
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from types import ModuleType
from typing import TYPE_CHECKING, Literal

from uavmpc.comms.message import InvalidMessageError

if TYPE_CHECKING:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import (
        Ed25519PrivateKey,
        Ed25519PublicKey,
    )

__all__ = ["MIN_KEY_BYTES", "SIGNATURE_BYTES", "CommandGate", "CommandSigner", "Identity",
           "Roster", "RosterEntry", "SharedKey", "Unsealed", "check_key", "load_identity",
           "load_key", "load_roster", "seal", "sign", "unseal", "verify"]

AUTH_MAGIC = b"UAVS"
TAG_BYTES = hashlib.sha256().digest_size
#: Bytes appended by :func:`sign`.
SIGNATURE_BYTES = len(AUTH_MAGIC) + TAG_BYTES
#: Shortest key accepted (128 bits).
MIN_KEY_BYTES = 16
#: Longest key file read (a key file is small; anything larger is the wrong file).
MAX_KEY_FILE_BYTES = 4096
#: Longest roster file read (thousands of members; anything larger is the wrong file).
MAX_ROSTER_FILE_BYTES = 1 << 20
_CONTEXT = b"uavmpc-auth-v1\0"
_HEX_RE = re.compile(r"[0-9A-Fa-f]+")


def sign(data: bytes, key: bytes) -> bytes:
    """``data`` followed by the authentication trailer (see the module docstring)."""
    data = _as_bytes(data, "data")
    check_key(key)
    return data + AUTH_MAGIC + _tag(data, key)


def verify(signed: bytes, key: bytes) -> bytes:
    """The message inside ``signed``; raises :class:`InvalidMessageError` whose text starts with
    ``"unsigned message"`` (no trailer) or ``"forged message (bad signature)"`` (a trailer that
    does not match: tampered with, or signed with another key)."""
    check_key(key)
    if not isinstance(signed, bytes | bytearray | memoryview):
        raise InvalidMessageError(f"data: expected bytes, got {type(signed).__name__}")
    signed = bytes(signed)
    if len(signed) < SIGNATURE_BYTES or signed[-SIGNATURE_BYTES:-TAG_BYTES] != AUTH_MAGIC:
        raise InvalidMessageError(
            f"unsigned message: no {SIGNATURE_BYTES}-byte signature trailer "
            f"({len(signed)} bytes)")
    data, tag = signed[:-TAG_BYTES - len(AUTH_MAGIC)], signed[-TAG_BYTES:]
    if not hmac.compare_digest(tag, _tag(data, key)):
        raise InvalidMessageError(
            "forged message (bad signature): the tag does not match (tampered with, or "
            "signed with another key)")
    return data


def load_key(path: str | os.PathLike[str]) -> bytes:
    """The key in the file at ``path``: hex digits (whitespace around them ignored, e.g. the
    output of ``secrets.token_hex(32)``) or else raw bytes, at least :data:`MIN_KEY_BYTES`.

    Raises:
        ValueError: unreadable, too large, odd-length hex or too little key material (the text
            names the file and the problem).
    """
    raw, where = _read_private(path)
    text = raw.strip(string.whitespace.encode())
    try:
        ascii_text = text.decode("ascii")
    except UnicodeDecodeError:
        ascii_text = None
    if ascii_text and _HEX_RE.fullmatch(ascii_text):
        if len(ascii_text) % 2:
            raise ValueError(f"{where}: {len(ascii_text)} hex digits, an odd number")
        key = bytes.fromhex(ascii_text)
        kind = "hex-decoded"
    else:
        key = raw
        kind = "raw"
    if len(key) < MIN_KEY_BYTES:
        raise ValueError(
            f"{where}: {len(key)} bytes of key material ({kind}), need at least "
            f"{MIN_KEY_BYTES} (e.g. 64 hex digits from secrets.token_hex(32))")
    return key


def _tag(data: bytes, key: bytes) -> bytes:
    return hmac.new(key, _CONTEXT + data + AUTH_MAGIC, hashlib.sha256).digest()


def _as_bytes(value: object, name: str) -> bytes:
    if not isinstance(value, bytes | bytearray | memoryview):
        raise TypeError(f"{name}: expected bytes, got {type(value).__name__}")
    return bytes(value)


def check_key(key: object) -> None:
    """Raise ``TypeError``/``ValueError`` unless ``key`` is bytes of a usable length."""
    if not isinstance(key, bytes | bytearray):
        raise TypeError(f"key: expected bytes, got {type(key).__name__}")
    if len(key) < MIN_KEY_BYTES:
        raise ValueError(f"key: {len(key)} bytes, need at least {MIN_KEY_BYTES}")


def _read_private(path: str | os.PathLike[str]) -> tuple[bytes, str]:
    """The bytes of a key file, refused when others may read it (as ssh does: a key someone
    else can read may be someone else's too)."""
    where = f"key file {os.fspath(path)!r}"
    try:
        with open(path, "rb") as f:
            mode = os.fstat(f.fileno()).st_mode
            raw = f.read(MAX_KEY_FILE_BYTES + 1)
    except (OSError, ValueError) as exc:  # ValueError: a NUL in the path
        raise ValueError(f"{where}: cannot read it ({_reason(exc)})") from None
    if os.name == "posix" and mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ValueError(f"{where}: readable by others (mode {stat.S_IMODE(mode):04o}); "
                         f"chmod 600 {os.fspath(path)}")
    if len(raw) > MAX_KEY_FILE_BYTES:
        raise ValueError(f"{where}: larger than {MAX_KEY_FILE_BYTES} bytes, not a key file")
    return raw, where


def _reason(exc: OSError | ValueError) -> str:
    return getattr(exc, "strerror", None) or str(exc)


# --------------------------------------------------------------------------- identities
SEAL_MAGIC = b"UAVA"
SCHEME_SHARED = 1
SCHEME_ED25519 = 2
_TAG_LEN = {SCHEME_SHARED: TAG_BYTES, SCHEME_ED25519: 64}
_CONTEXT_V2 = b"uavmpc-auth-v2\0"
_MEMBER_ID = re.compile(r"[A-Za-z0-9_-]{1,32}")
Role = Literal["uav", "operator"]
ROLES: tuple[str, ...] = ("uav", "operator")
ED25519_KEY_BYTES = 32


def _ed25519() -> ModuleType:
    try:
        from cryptography.hazmat.primitives.asymmetric import ed25519
    except ImportError:
        raise ImportError("per-member identities need the cryptography package: "
                          "pip install 'uavmpc[auth]'") from None
    return ed25519


def check_member_id(member_id: object, what: str = "member id") -> str:
    """``member_id`` if it is 1–32 characters of ``[A-Za-z0-9_-]`` (a UAV or operator id)."""
    # fullmatch: with match and "^...$", "$" also matches before a trailing newline.
    if not isinstance(member_id, str) or not _MEMBER_ID.fullmatch(member_id):
        raise ValueError(f"{what}: must be 1-32 characters of [A-Za-z0-9_-], got {member_id!r}")
    return member_id


@dataclass(frozen=True)
class SharedKey:
    """The swarm's shared key as a signer and verifier: whoever holds it may sign as
    ``member_id`` (or as anyone: the mode does not tell members apart)."""

    key: bytes
    member_id: str = "swarm"

    def __post_init__(self) -> None:
        check_key(self.key)
        check_member_id(self.member_id)


@dataclass(frozen=True, repr=False)
class Identity:
    """One member's Ed25519 private key (the 32-byte seed) and the id it signs as."""

    member_id: str
    private_key: bytes = field(repr=False)

    def __post_init__(self) -> None:
        check_member_id(self.member_id)
        if not isinstance(self.private_key, bytes) or len(self.private_key) != ED25519_KEY_BYTES:
            raise ValueError(f"identity {self.member_id!r}: the private key must be "
                             f"{ED25519_KEY_BYTES} bytes")

    def __repr__(self) -> str:
        return f"Identity({self.member_id!r})"

    @classmethod
    def generate(cls, member_id: str) -> Identity:
        """A new random identity."""
        ed = _ed25519()  # first: without the extra, its message names it
        from cryptography.hazmat.primitives import serialization

        raw = ed.Ed25519PrivateKey.generate().private_bytes(
            serialization.Encoding.Raw, serialization.PrivateFormat.Raw,
            serialization.NoEncryption())
        return cls(member_id, raw)

    @property
    def public_key(self) -> bytes:
        """The 32-byte public key (what the roster holds)."""
        key = self._key()  # first: without the extra, its message names it
        from cryptography.hazmat.primitives import serialization

        return key.public_key().public_bytes(serialization.Encoding.Raw,
                                             serialization.PublicFormat.Raw)

    def _key(self) -> Ed25519PrivateKey:
        cached = self.__dict__.get("_cached")
        if cached is None:
            cached = _ed25519().Ed25519PrivateKey.from_private_bytes(self.private_key)
            object.__setattr__(self, "_cached", cached)
        return cached

    def _sign(self, data: bytes) -> bytes:
        return bytes(self._key().sign(data))


@dataclass(frozen=True)
class RosterEntry:
    """A member of the swarm: its role and its public key."""

    role: Role
    public_key: bytes


class Roster(Mapping[str, RosterEntry]):
    """The swarm's members (id → :class:`RosterEntry`): who may sign what. UAVs sign their own
    predictions; operators sign commands."""

    def __init__(self, members: Mapping[str, RosterEntry]) -> None:
        ed = _ed25519()
        self._members = dict(members)
        self._keys: dict[str, Ed25519PublicKey] = {}
        for mid, entry in self._members.items():
            check_member_id(mid, "roster member id")
            if entry.role not in ROLES:
                raise ValueError(f"roster member {mid!r}: role must be one of {ROLES}, "
                                 f"got {entry.role!r}")
            if len(entry.public_key) != ED25519_KEY_BYTES:
                raise ValueError(f"roster member {mid!r}: public key must be "
                                 f"{ED25519_KEY_BYTES} bytes, got {len(entry.public_key)}")
            self._keys[mid] = ed.Ed25519PublicKey.from_public_bytes(entry.public_key)

    @classmethod
    def of(cls, identities: Iterable[tuple[Identity, Role]]) -> Roster:
        """The roster of these identities (tests, and ``uavmpc keygen``)."""
        return cls({ident.member_id: RosterEntry(role, ident.public_key)
                    for ident, role in identities})

    def __getitem__(self, member_id: str) -> RosterEntry:
        return self._members[member_id]

    def __iter__(self) -> Iterator[str]:
        return iter(self._members)

    def __len__(self) -> int:
        return len(self._members)

    def _verify(self, member_id: str, tag: bytes, data: bytes) -> bool:
        from cryptography.exceptions import InvalidSignature

        try:
            self._keys[member_id].verify(tag, data)
        except InvalidSignature:
            return False
        return True

    def to_toml(self) -> str:
        """The roster file's text (see :func:`load_roster`)."""
        lines = ["# uavmpc swarm roster: who may sign what (public keys only)."]
        for mid, e in self._members.items():
            lines += ["", f"[members.{mid}]", f'role = "{e.role}"',
                      f'public_key = "{e.public_key.hex()}"']
        return "\n".join(lines) + "\n"


def load_roster(path: str | os.PathLike[str]) -> Roster:
    """A roster file::

        [members.uav1]
        role = "uav"            # or "operator"
        public_key = "64 hex digits"

    Raises:
        ValueError: unreadable or invalid (the text names the file and the field).
    """
    from uavmpc.config import ConfigError, reject_unknown

    where = f"roster {os.fspath(path)!r}"
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_ROSTER_FILE_BYTES + 1)
    except (OSError, ValueError) as exc:  # ValueError: a NUL in the path
        raise ValueError(f"{where}: cannot read it ({_reason(exc)})") from None
    if len(raw) > MAX_ROSTER_FILE_BYTES:
        raise ValueError(f"{where}: larger than {MAX_ROSTER_FILE_BYTES} bytes, not a roster")
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ValueError(f"{where}: not UTF-8 text (byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{where}: invalid TOML: {exc}") from None
    except RecursionError:  # tomllib recurses into nested arrays and tables
        raise ValueError(f"{where}: invalid TOML: nested too deeply") from None
    try:
        reject_unknown(data, {"members"}, where)
        members = data.get("members")
        if not isinstance(members, dict) or not members:
            raise ConfigError(f"{where}: needs at least one [members.<id>] table")
        out = {}
        for mid, t in members.items():
            prefix = f"{where}: members.{mid}"
            if not isinstance(t, dict):
                raise ConfigError(f"{prefix}: must be a table")
            reject_unknown(t, {"role", "public_key"}, prefix)
            role, pub = t.get("role"), t.get("public_key")
            if role not in ROLES:
                raise ConfigError(f"{prefix}.role: must be one of {ROLES}, got {role!r}")
            if not isinstance(pub, str) or not re.fullmatch(r"[0-9A-Fa-f]{64}", pub):
                raise ConfigError(f"{prefix}.public_key: must be 64 hex digits")
            out[mid] = RosterEntry(role, bytes.fromhex(pub))
        return Roster(out)
    except ConfigError as exc:
        raise ValueError(str(exc)) from None
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def load_identity(path: str | os.PathLike[str]) -> Identity:
    """An identity file (written by ``uavmpc keygen``): ``<id> <64 hex digits of the private
    key>`` on one line, readable by its owner only.

    Raises:
        ValueError: unreadable, readable by others, or malformed (the text says which).
    """
    raw, where = _read_private(path)
    try:
        parts = raw.decode("ascii").split()
    except UnicodeDecodeError:
        parts = []
    if len(parts) != 2 or not re.fullmatch(r"[0-9A-Fa-f]{64}", parts[1]):
        raise ValueError(f"{where}: not an identity file (expected '<id> <64 hex digits>')")
    try:
        return Identity(parts[0], bytes.fromhex(parts[1]))
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def write_identity(identity: Identity, path: str | os.PathLike[str]) -> None:
    """Write ``identity`` to a new file readable by its owner only (never overwrites)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(f"{identity.member_id} {identity.private_key.hex()}\n")


Signer = SharedKey | Identity
Verifier = SharedKey | Roster


def seal(data: bytes, channel: str, signer: Signer, seq: int) -> bytes:
    """``data`` with the trailer of the module docstring: signed by ``signer`` for ``channel``
    with sequence number ``seq`` (0 ≤ seq < 2⁶⁴)."""
    data = _as_bytes(data, "data")
    if not 0 <= seq < 2**64:
        raise ValueError(f"seq: must be in [0, 2^64), got {seq}")
    scheme = SCHEME_ED25519 if isinstance(signer, Identity) else SCHEME_SHARED
    sid = signer.member_id.encode("ascii")
    head = data + SEAL_MAGIC + bytes([scheme]) + sid + bytes([len(sid)]) + seq.to_bytes(8, "little")
    signed = _CONTEXT_V2 + channel.encode() + b"\0" + head
    if isinstance(signer, Identity):
        return head + signer._sign(signed)
    return head + hmac.new(signer.key, signed, hashlib.sha256).digest()


@dataclass(frozen=True)
class Unsealed:
    """What :func:`unseal` found: the message, who signed it, its sequence number."""

    data: bytes
    signer_id: str
    seq: int


def unseal(sealed: bytes, channel: str, verifier: Verifier) -> Unsealed:
    """Check a :func:`seal` ed message for ``channel``; raises :class:`InvalidMessageError`
    starting with ``"unsigned message"``, ``"forged message (bad signature)"`` (also: signed
    for another channel) or ``"unknown signer"`` (not in the roster)."""
    if not isinstance(sealed, bytes | bytearray | memoryview):
        raise InvalidMessageError(f"data: expected bytes, got {type(sealed).__name__}")
    b = bytes(sealed)
    scheme = SCHEME_ED25519 if isinstance(verifier, Roster) else SCHEME_SHARED
    tag_len = _TAG_LEN[scheme]
    end = len(b) - tag_len  # the seq's end
    ok = end >= 8 + 1 + 1 + 1 + len(SEAL_MAGIC)
    n_id = b[end - 9] if ok else 0
    start = end - 9 - n_id - 1 - len(SEAL_MAGIC)  # where the magic starts
    if not ok or n_id < 1 or start < 0 or b[start:start + 4] != SEAL_MAGIC:
        raise InvalidMessageError(f"unsigned message: no identity trailer ({len(b)} bytes)")
    if b[start + 4] != scheme:
        raise InvalidMessageError(
            f"unsigned message: signed with scheme {b[start + 4]}, expected {scheme} "
            f"({'identities' if scheme == SCHEME_ED25519 else 'shared key'})")
    try:
        signer_id = b[start + 5:start + 5 + n_id].decode("ascii")
        check_member_id(signer_id)
    except (UnicodeDecodeError, ValueError):
        raise InvalidMessageError("forged message (bad signature): malformed signer id") from None
    seq = int.from_bytes(b[end - 8:end], "little")
    signed = _CONTEXT_V2 + channel.encode() + b"\0" + b[:end]
    tag = b[end:]
    if isinstance(verifier, Roster):
        if signer_id not in verifier:
            raise InvalidMessageError(f"unknown signer: {signer_id!r} is not in the roster")
        good = verifier._verify(signer_id, tag, signed)
    else:
        good = hmac.compare_digest(tag, hmac.new(verifier.key, signed, hashlib.sha256).digest())
    if not good:
        raise InvalidMessageError(
            f"forged message (bad signature): from {signer_id!r} on {channel!r} (tampered "
            "with, signed with another key, or for another channel)")
    return Unsealed(b[:start], signer_id, seq)


class CommandSigner:
    """Seals commands with strictly increasing sequence numbers: the signer's clock in µs, or
    one more than the last if the clock stood still or went back."""

    def __init__(self, signer: Signer, clock: Callable[[], float] = time.time) -> None:
        self.signer = signer
        self._clock = clock
        self._last = 0

    def seal(self, data: bytes, channel: str) -> bytes:
        """``data`` sealed for ``channel`` with the next sequence number."""
        seq = max(self._last + 1, int(self._clock() * 1e6))
        self._last = seq
        return seal(data, channel, self.signer, seq)


#: How :class:`CommandGate` counts refusals (each error's text starts with its kind).
REFUSALS = ("unsigned", "forged", "unknown signer", "not allowed", "replayed", "stale")


class CommandGate:
    """The receiving side of a command channel: only sealed commands from signers allowed on
    it, each newer than the last one of its signer.

    Args:
        verifier: the shared key, or the roster (then only members with a role in ``roles``
            may command, e.g. operators).
        roles: with a roster, who may send commands here.
        max_skew_s: refuse commands whose sequence number (the signer's clock in µs) is
            further than this from ``now_s`` (a replay after the receiver restarted; needs
            clocks within this much). None: no age check.
    Counts every refusal in :attr:`rejected` by kind: ``unsigned``, ``forged``,
    ``unknown signer``, ``not allowed``, ``replayed``, ``stale``.
    """

    def __init__(self, verifier: Verifier, *, roles: tuple[str, ...] = ("operator",),
                 max_skew_s: float | None = None) -> None:
        self.verifier = verifier
        self.roles = roles
        self.max_skew_s = max_skew_s
        self._last: dict[str, int] = {}
        self.accepted = 0
        self.rejected: dict[str, int] = {}

    def open(self, sealed: bytes, channel: str, now_s: float) -> Unsealed:
        """The command inside ``sealed``, or :class:`InvalidMessageError` (counted)."""
        try:
            out = unseal(sealed, channel, self.verifier)
            if isinstance(self.verifier, Roster) and \
                    self.verifier[out.signer_id].role not in self.roles:
                raise InvalidMessageError(
                    f"not allowed: {out.signer_id!r} is a {self.verifier[out.signer_id].role}, "
                    f"only {'/'.join(self.roles)} may command on {channel!r}")
            last = self._last.get(out.signer_id, -1)
            if out.seq <= last:
                raise InvalidMessageError(
                    f"replayed message: seq {out.seq} from {out.signer_id!r} is not newer "
                    f"than {last}")
            if self.max_skew_s is not None and abs(out.seq * 1e-6 - now_s) > self.max_skew_s:
                raise InvalidMessageError(
                    f"stale message: sent at {out.seq * 1e-6:.3f} s, now {now_s:.3f} s "
                    f"(more than {self.max_skew_s} s apart)")
        except InvalidMessageError as exc:
            text = str(exc)
            kind = next((k for k in REFUSALS if text.startswith(k)), "invalid")
            self.rejected[kind] = self.rejected.get(kind, 0) + 1
            raise
        self._last[out.signer_id] = out.seq
        self.accepted += 1
        return out

"""Optional shared-key authentication of messages (HMAC-SHA256).

A receiver that holds the swarm's key can tell a message from a member of the swarm from one
forged by anyone else on the link: a forged prediction crossing our path would otherwise make
us climb (a non-cooperative intruder), or a forged high-priority one pin us down.

Wire format: the message bytes, then a 36-byte trailer::

    message || b"UAVS" || HMAC-SHA256(key, b"uavmpc-auth-v1\\0" || message || b"UAVS")

(the full 32-byte tag). Senders sign ``sign(encode(msg), key)``; an
:class:`~uavmpc.comms.link.Inbox` given the key verifies before it decodes, and counts
``"unsigned message"`` and ``"forged message (bad signature)"`` rejections like any other.

What this does NOT do:

- Encrypt: anyone on the link can still read the predictions (use TLS, see
  :mod:`uavmpc.comms.zenoh_link`, where that matters).
- Prevent replays: a recorded genuine message can be sent again. The receipt check of
  :class:`~uavmpc.comms.link.Inbox` (``max_age_s`` with synchronised clocks) bounds the window,
  and a replay is never newer than what the inbox already holds from that sender.
- Tell members apart: every holder of the shared key can sign as any UAV id.

Keys: at least :data:`MIN_KEY_BYTES` random bytes (``python -c "import secrets;
print(secrets.token_hex(32))" > swarm.key``), readable only by the flight software
(``chmod 600``); load them with :func:`load_key`.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import re
import string
from typing import Any

from uavmpc.comms.message import InvalidMessageError

__all__ = ["MIN_KEY_BYTES", "SIGNATURE_BYTES", "check_key", "load_key", "sign", "verify"]

AUTH_MAGIC = b"UAVS"
TAG_BYTES = hashlib.sha256().digest_size
#: Bytes appended by :func:`sign`.
SIGNATURE_BYTES = len(AUTH_MAGIC) + TAG_BYTES
#: Shortest key accepted (128 bits).
MIN_KEY_BYTES = 16
#: Longest key file read (a key file is small; anything larger is the wrong file).
MAX_KEY_FILE_BYTES = 4096
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
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_KEY_FILE_BYTES + 1)
    except OSError as exc:
        raise ValueError(f"key file {os.fspath(path)!r}: cannot read it ({exc.strerror})") from None
    where = f"key file {os.fspath(path)!r}"
    if len(raw) > MAX_KEY_FILE_BYTES:
        raise ValueError(f"{where}: larger than {MAX_KEY_FILE_BYTES} bytes, not a key file")
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


def _as_bytes(value: Any, name: str) -> bytes:
    if not isinstance(value, bytes | bytearray | memoryview):
        raise TypeError(f"{name}: expected bytes, got {type(value).__name__}")
    return bytes(value)


def check_key(key: Any) -> None:
    """Raise ``TypeError``/``ValueError`` unless ``key`` is bytes of a usable length."""
    if not isinstance(key, bytes | bytearray):
        raise TypeError(f"key: expected bytes, got {type(key).__name__}")
    if len(key) < MIN_KEY_BYTES:
        raise ValueError(f"key: {len(key)} bytes, need at least {MIN_KEY_BYTES}")

"""A MAVLink 2 endpoint on UDP (pymavlink's codec over a socket of our own).

Addresses follow MAVSDK's: ``udp://[HOST]:PORT`` (or ``udpin://``) listens on PORT and answers
whoever sent the last message it chose to trust (:meth:`MavlinkEndpoint.trust`);
``udpout://HOST:PORT`` sends to HOST:PORT from a port of its own. A serial autopilot is reached
through a router (mavlink-router or MAVProxy on the companion computer, forwarding to UDP).
"""

from __future__ import annotations

import select
import socket
import struct
import sys
import time
from dataclasses import dataclass

from uavmpc.drivers.px4.dialect import mavlink

__all__ = ["MavlinkAddress", "MavlinkEndpoint", "parse_address"]

#: Largest datagram read (a MAVLink 2 frame is at most 280 bytes; routers may pack several).
_MAX_DATAGRAM = 65535
#: Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS): the kernel stamps each datagram on arrival, so
#: the age of a state is measured from when it arrived, not from when we got round to reading.
_SO_TIMESTAMPNS = 35
_STAMPED = sys.platform == "linux"
_TIMESPEC = struct.Struct("qq")


class InvalidAddressError(ValueError):
    """A MAVLink address that is not ``udp://[host]:port`` or ``udpout://host:port``."""


@dataclass(frozen=True)
class MavlinkAddress:
    """A parsed address: ``listen`` binds (host, port); otherwise it sends to (host, port)."""

    listen: bool
    host: str
    port: int

    def __str__(self) -> str:
        return f"{'udp' if self.listen else 'udpout'}://{self.host}:{self.port}"


def parse_address(url: str) -> MavlinkAddress:
    """``udp://:14540``, ``udp://0.0.0.0:14540``, ``udpin://…`` or ``udpout://127.0.0.1:14580``.

    Raises:
        InvalidAddressError: naming what is wrong.
    """
    scheme, sep, rest = str(url).partition("://")
    if not sep or scheme not in ("udp", "udpin", "udpout"):
        raise InvalidAddressError(
            f"MAVLink address {url!r}: expected udp://[HOST]:PORT (listen) or "
            "udpout://HOST:PORT (send to); for a serial port run mavlink-router to UDP")
    host, colon, port_text = rest.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not colon or not 0 < port < 65536:
        raise InvalidAddressError(f"MAVLink address {url!r}: needs a port in 1..65535")
    listen = scheme != "udpout"
    if not host:
        if not listen:
            raise InvalidAddressError(f"MAVLink address {url!r}: udpout needs a host")
        host = "0.0.0.0"
    return MavlinkAddress(listen, host, port)


class MavlinkEndpoint:
    """One UDP socket speaking MAVLink 2 as (``system_id``, ``component_id``).

    :meth:`receive` never blocks and never raises on what arrives: bytes that are not valid
    MAVLink are counted in :attr:`garbage`; the caller decides which senders it trusts.
    """

    def __init__(self, address: str | MavlinkAddress, *, system_id: int,
                 component_id: int) -> None:
        self.address = address if isinstance(address, MavlinkAddress) else parse_address(address)
        self.mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self.mav.robust_parsing = True
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self._stamped = _STAMPED
        if self._stamped:
            try:
                self.sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
            except OSError:
                self._stamped = False
        if self.address.listen:
            try:
                self.sock.bind((self.address.host, self.address.port))
            except OSError as exc:
                self.sock.close()
                raise OSError(f"cannot listen on {self.address}: {exc.strerror}") from None
            self.peer: tuple[str, int] | None = None
        else:
            self.sock.bind(("0.0.0.0", 0))
            self.peer = (self.address.host, self.address.port)
        self.garbage = 0
        #: Frames of message ids outside the dialect, by id: PX4 v1.16 sends four such (8,
        #: 380, 411, 436) on its onboard link. Not garbage, but not readable either.
        self.unknown_ids: dict[int, int] = {}
        self.sent = 0

    @property
    def local_port(self) -> int:
        return int(self.sock.getsockname()[1])

    def trust(self, sender: tuple[str, int]) -> None:
        """Answer ``sender`` from now on (a listening endpoint; called for trusted messages)."""
        if self.address.listen:
            self.peer = sender

    def send(self, message: mavlink.MAVLink_message) -> bool:
        """Pack and send; False when there is no peer yet (a listener nobody talked to)."""
        if self.peer is None:
            return False
        data = message.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        try:
            self.sock.sendto(data, self.peer)
        except OSError:  # the peer's port closed (ICMP unreachable): the link is down
            return False
        self.sent += 1
        return True

    def receive(self, max_datagrams: int = 64
                ) -> list[tuple[mavlink.MAVLink_message, tuple[str, int], float]]:
        """What arrived: (message, sender, arrival time [s, Unix]); at most ``max_datagrams``
        datagrams (a flood waits in the socket's buffer, where the kernel drops it, instead of
        starving us)."""
        out = []
        for _ in range(max_datagrams):
            try:
                data, arrived, sender = self._read()
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. ICMP port unreachable reported on the next read
                continue
            try:
                messages = self.mav.parse_buffer(data) or []
            except Exception:  # pymavlink raises bare MAVError/struct errors on odd frames
                messages = []
                self.garbage += 1
            if len(self.mav.buf) > self.mav.buf_index:
                # A datagram holds whole frames: a partial one left over is garbage, and must
                # not swallow the start of the next datagram.
                self.garbage += 1
                self._reset_parser()
            for m in messages:
                kind = m.get_type()
                if kind.startswith("UNKNOWN_"):
                    # Its CRC cannot be checked (no CRC extra): counted by id, never used.
                    msg_id = int(kind.removeprefix("UNKNOWN_"))
                    self.unknown_ids[msg_id] = self.unknown_ids.get(msg_id, 0) + 1
                elif kind == "BAD_DATA":
                    self.garbage += 1
                else:
                    out.append((m, sender, arrived))
        return out

    def drain(self) -> int:
        """Drop every datagram queued on the socket (what arrived while nobody read is
        history); the number dropped."""
        dropped = 0
        while True:
            try:
                self.sock.recv(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return dropped
            except OSError:
                continue
            dropped += 1

    def _read(self) -> tuple[bytes, float, tuple[str, int]]:
        if not self._stamped:
            data, sender = self.sock.recvfrom(_MAX_DATAGRAM)
            return data, time.time(), sender
        data, ancillary, _flags, sender = self.sock.recvmsg(_MAX_DATAGRAM,
                                                            socket.CMSG_SPACE(16))
        for level, kind, payload in ancillary:
            if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(payload) >= 16:
                sec, nsec = _TIMESPEC.unpack_from(payload)
                if sec:
                    return data, sec + nsec * 1e-9, sender
        return data, time.time(), sender

    def _reset_parser(self) -> None:
        self.mav.buf = bytearray()
        self.mav.buf_index = 0
        self.mav.expected_length = mavlink.HEADER_LEN_V1 + 2
        self.mav.have_prefix_error = False

    def wait(self, timeout_s: float) -> bool:
        """Block until something arrives or ``timeout_s`` passes; True if readable."""
        if timeout_s <= 0.0:
            return False
        readable, _, _ = select.select([self.sock], [], [], timeout_s)
        return bool(readable)

    def close(self) -> None:
        self.sock.close()

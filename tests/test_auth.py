"""Shared-key message authentication, and an Inbox that only believes signed messages."""

import numpy as np
import pytest

from uavmpc.avoidance import HeightOffsetStrategy
from uavmpc.comms.auth import SIGNATURE_BYTES, load_key, sign, verify
from uavmpc.comms.link import Inbox, SimulatedLink
from uavmpc.comms.message import SCHEMA_VERSION, InvalidMessageError, PredictionMessage, encode

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
HORIZON = np.cumsum(np.r_[0.01, np.full(39, 0.2)])


def _msg(uav_id: str = "uav2", stamp: float = 10.0) -> bytes:
    path = np.column_stack([np.linspace(0, 10, 40), np.zeros(40), np.full(40, 5.0)])
    return encode(PredictionMessage(SCHEMA_VERSION, uav_id, 2, stamp, stamp + HORIZON, path, True))


def _intruder(stamp: float) -> bytes:
    """A non-cooperative prediction right through our path (as in tests/test_world.py)."""
    path = np.column_stack([np.linspace(-25, 25, 40), np.zeros(40), np.full(40, 5.0)])
    return encode(PredictionMessage(SCHEMA_VERSION, "intruder", 0, stamp, stamp + HORIZON, path,
                                    False))


def test_round_trip() -> None:
    data = _msg()
    signed = sign(data, KEY)
    assert len(signed) == len(data) + SIGNATURE_BYTES
    assert signed.startswith(data)
    assert verify(signed, KEY) == data
    assert verify(bytearray(signed), KEY) == data
    assert verify(sign(b"", KEY), KEY) == b""


def _flip(data: bytes, i: int) -> bytes:
    b = bytearray(data)
    b[i] ^= 0x01
    return bytes(b)


@pytest.mark.parametrize(("make", "reason"), [
    (lambda d: d, "unsigned message"),
    (lambda d: b"", "unsigned message"),
    (lambda d: sign(d, KEY)[:-1], "unsigned message"),  # trailer cut: magic not where expected
    (lambda d: _flip(sign(d, KEY), 30), "forged message (bad signature)"),  # in the message
    (lambda d: _flip(sign(d, KEY), -1), "forged message (bad signature)"),  # in the tag
    (lambda d: sign(d, OTHER_KEY), "forged message (bad signature)"),  # wrong key
    (lambda d: sign(d, KEY)[1:], "forged message (bad signature)"),  # message truncated
    (lambda d: b"x" + sign(d, KEY), "forged message (bad signature)"),  # junk prepended
])
def test_unsigned_and_forged_are_rejected_with_the_reason(make, reason) -> None:
    with pytest.raises(InvalidMessageError) as info:
        verify(make(_msg()), KEY)
    assert str(info.value).split(":", 1)[0] == reason


def test_short_or_wrong_keys_are_refused() -> None:
    with pytest.raises(ValueError, match="at least 16"):
        sign(b"x", b"short")
    with pytest.raises(ValueError, match="at least 16"):
        verify(b"x" * 40, b"short")
    with pytest.raises(TypeError, match="key"):
        sign(b"x", "a string key" * 4)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="key"):
        Inbox("uav1", key=b"short")


def _private(path, data: bytes):  # type: ignore[no-untyped-def]
    """A key file as a user makes one: ``chmod 600`` (others reading it is refused)."""
    path.write_bytes(data)
    path.chmod(0o600)
    return path


def test_load_key(tmp_path) -> None:
    hexfile = _private(tmp_path / "hex.key", (KEY.hex() + "\n").encode())
    assert load_key(hexfile) == KEY
    raw = _private(tmp_path / "raw.key", b"\x00\xff" * 10)
    assert load_key(str(raw)) == b"\x00\xff" * 10
    short = _private(tmp_path / "short.key", b"00112233445566778899\n")  # 10 bytes of hex
    with pytest.raises(ValueError, match=r"short\.key.*10 bytes of key material"):
        load_key(short)
    odd = _private(tmp_path / "odd.key", b"0" * 33)
    with pytest.raises(ValueError, match="odd"):
        load_key(odd)
    with pytest.raises(ValueError, match=r"missing\.key.*cannot read"):
        load_key(tmp_path / "missing.key")
    big = _private(tmp_path / "big.key", b"a" * 10_000)
    with pytest.raises(ValueError, match="not a key file"):
        load_key(big)


def test_inbox_with_a_key_counts_unsigned_and_forged_and_accepts_signed() -> None:
    inbox = Inbox("uav1", key=KEY)
    assert inbox.accept(_msg(stamp=10.0), 10.0) is None
    assert inbox.accept(_flip(sign(_msg(stamp=10.1), KEY), 40), 10.1) is None
    assert inbox.accept(sign(_msg(stamp=10.2), OTHER_KEY), 10.2) is None
    assert inbox.accept(sign(b"garbage", KEY), 10.2) is None  # authentic, still malformed
    assert inbox.rejected == {"unsigned message": 1, "forged message (bad signature)": 2,
                              "truncated": 1}
    assert "uav2" not in inbox.latest
    msg = inbox.accept(sign(_msg(stamp=10.3), KEY), 10.3)
    assert msg is not None and msg.stamp_s == 10.3
    assert inbox.latest["uav2"] is msg
    assert inbox.accepted == 1
    # Without a key, signed messages are not understood (the trailer makes them oversized).
    plain = Inbox("uav1")
    assert plain.accept(sign(_msg(stamp=10.3), KEY), 10.3) is None
    assert plain.rejected == {"oversized": 1}


def _decision(inbox: Inbox, now: float):
    """Our own straight path along x at 5 m (where the intruder flies)."""
    own = np.column_stack([np.linspace(-5, 5, 40), np.zeros(40), np.full(40, 5.0)])
    return HeightOffsetStrategy().update(now, "uav1", 1, now + HORIZON, own, inbox.latest)


def test_a_forged_intruder_does_not_make_us_climb() -> None:
    link = SimulatedLink(["uav1", "attacker", "uav2"])
    now = 5.0
    link.publish(_intruder(now), "attacker", now)  # unsigned
    link.publish(sign(_intruder(now + 0.01), OTHER_KEY), "attacker", now)  # wrong key
    trusting, keyed = Inbox("uav1"), Inbox("uav1", key=KEY)
    for data in link.receive("uav1", now):
        trusting.accept(data, now)
        keyed.accept(data, now)
    # Without authentication the intruder is believed and we climb out of its way ...
    assert "intruder" in trusting.latest
    fooled = _decision(trusting, now)
    assert fooled.z_offset_m > 0.0 and "intruder" in fooled.yielding_to
    # ... with it, the forgery is counted and ignored: no climb.
    assert "intruder" not in keyed.latest
    assert keyed.rejected == {"unsigned message": 1, "forged message (bad signature)": 1}
    calm = _decision(keyed, now)
    assert calm.z_offset_m == 0.0 and not calm.conflicts
    # A genuine (signed) non-cooperative UAV on our path still makes us climb.
    link.publish(sign(_intruder(now + 0.1), KEY), "uav2", now + 0.1)
    keyed.poll(link, now + 0.1)
    assert _decision(keyed, now + 0.1).z_offset_m > 0.0

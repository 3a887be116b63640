"""Who may speak: per-member Ed25519 identities, sealed commands, replays, key files."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

pytest.importorskip("cryptography")

from uavmpc.comms.auth import (
    CommandGate,
    CommandSigner,
    Identity,
    Roster,
    SharedKey,
    load_identity,
    load_key,
    load_roster,
    seal,
    sign,
    unseal,
    write_identity,
)
from uavmpc.comms.link import PREDICTION_CHANNEL, Inbox
from uavmpc.comms.message import SCHEMA_VERSION, InvalidMessageError, PredictionMessage, encode

KEY = b"0123456789abcdef0123456789abcdef"
HORIZON = np.cumsum(np.r_[0.01, np.full(39, 0.2)])
GCS = Identity.generate("gcs")
UAV1 = Identity.generate("uav1")
UAV2 = Identity.generate("uav2")
ROSTER = Roster.of([(GCS, "operator"), (UAV1, "uav"), (UAV2, "uav")])
MISSION = b'{"goto": [3.0, 0.0, 5.0, 0.0]}'


def _prediction(uav: str, stamp: float = 100.0) -> bytes:
    pos = np.tile([0.0, 0.0, 5.0], (40, 1))
    return encode(PredictionMessage(SCHEMA_VERSION, uav, 1, stamp, stamp + HORIZON, pos, True))


def test_seal_round_trip_and_every_byte_matters() -> None:
    sealed = seal(MISSION, "uav1/mission", GCS, 7)
    out = unseal(sealed, "uav1/mission", ROSTER)
    assert (out.data, out.signer_id, out.seq) == (MISSION, "gcs", 7)
    for i in range(len(sealed)):  # flip any bit anywhere: refused, never accepted
        bad = bytearray(sealed)
        bad[i] ^= 0x10
        with pytest.raises(InvalidMessageError):
            unseal(bytes(bad), "uav1/mission", ROSTER)
    with pytest.raises(InvalidMessageError, match=r"^forged"):  # signed for another UAV
        unseal(sealed, "uav2/mission", ROSTER)
    with pytest.raises(InvalidMessageError, match=r"^unsigned"):
        unseal(MISSION, "uav1/mission", ROSTER)
    stranger = Identity.generate("gcs")  # same id, a key the roster does not hold
    with pytest.raises(InvalidMessageError, match=r"^forged"):
        unseal(seal(MISSION, "uav1/mission", stranger, 8), "uav1/mission", ROSTER)
    with pytest.raises(InvalidMessageError, match=r"^unknown signer"):
        unseal(seal(MISSION, "uav1/mission", Identity.generate("eve"), 8), "uav1/mission",
               ROSTER)
    # A shared-key seal is not an identity's, and the other way round.
    shared = seal(MISSION, "uav1/mission", SharedKey(KEY, "gcs"), 9)
    with pytest.raises(InvalidMessageError, match=r"^unsigned"):
        unseal(shared, "uav1/mission", ROSTER)
    assert unseal(shared, "uav1/mission", SharedKey(KEY)).data == MISSION
    with pytest.raises(InvalidMessageError, match=r"^unsigned"):
        unseal(sealed, "uav1/mission", SharedKey(KEY))


def test_the_gate_refuses_replays_roles_and_stale_commands_and_counts_them() -> None:
    clock = [1000.0]
    signer = CommandSigner(GCS, clock=lambda: clock[0])
    gate = CommandGate(ROSTER, max_skew_s=30.0)
    first = signer.seal(MISSION, "uav1/mission")
    second = signer.seal(MISSION, "uav1/mission")  # the clock stood still: seq + 1
    assert gate.open(first, "uav1/mission", 1000.0).data == MISSION
    assert gate.open(second, "uav1/mission", 1000.0).seq == unseal(
        first, "uav1/mission", ROSTER).seq + 1
    refused = [
        (first, "replayed"),  # a recorded genuine command, sent again
        (CommandSigner(UAV2, clock=lambda: 2000.0).seal(MISSION, "uav1/mission"),
         "not allowed"),  # a member, but a UAV: it may not command another
        (MISSION, "unsigned"),
        (seal(MISSION, "uav1/mission", Identity.generate("gcs"), 10**16), "forged"),
    ]
    for data, kind in refused:
        with pytest.raises(InvalidMessageError, match=rf"^{kind}"):
            gate.open(data, "uav1/mission", 1000.0)
    clock[0] = 1100.0  # sent 100 s before the receiver's now: stale
    old = signer.seal(MISSION, "uav1/mission")
    with pytest.raises(InvalidMessageError, match=r"^stale"):
        gate.open(old, "uav1/mission", 1200.0)
    assert gate.accepted == 2
    assert gate.rejected == {"replayed": 1, "not allowed": 1, "unsigned": 1, "forged": 1,
                             "stale": 1}


def test_a_uav_cannot_speak_as_another() -> None:
    inbox = Inbox("uav1", roster=ROSTER, max_age_s=1e9)
    own = seal(_prediction("uav2"), PREDICTION_CHANNEL, UAV2, 0)
    assert inbox.accept(own, 100.0) is not None  # uav2 speaking as itself
    # uav2 holds a valid identity of the swarm, yet claims to be uav3 (or gcs): refused.
    for claimed in ("uav3", "gcs"):
        spoof = seal(_prediction(claimed, 100.5), PREDICTION_CHANNEL, UAV2, 1)
        assert inbox.accept(spoof, 100.5) is None
    # An operator's identity is not a UAV's; the shared key is no identity.
    assert inbox.accept(seal(_prediction("gcs", 100.6), PREDICTION_CHANNEL, GCS, 0),
                        100.6) is None
    assert inbox.accept(sign(_prediction("uav3", 100.7), KEY), 100.7) is None
    assert inbox.accept(_prediction("uav3", 100.8), 100.8) is None
    assert set(inbox.latest) == {"uav2"}
    assert inbox.rejected == {"wrong identity": 2, "not allowed": 1, "unsigned message": 2}


def test_stacks_with_identities_hear_each_other() -> None:
    from uavmpc.onboard import OnboardStack
    from uavmpc.plant import Airframe

    af = Airframe.packaged("f550")
    a = OnboardStack(af, uav_id="uav1", identity=UAV1, roster=ROSTER, position_m=(0, 0, 5))
    b = OnboardStack(af, uav_id="uav2", identity=UAV2, roster=ROSTER, position_m=(9, 0, 5))
    data = a.tick(0.0, _hover_state((0.0, 0.0, 5.0))).outgoing
    assert data is not None
    assert b.receive(0.01, [data])[0] is not None and "uav1" in b.inbox.latest
    with pytest.raises(ValueError, match="cannot sign as"):
        OnboardStack(af, uav_id="uav2", identity=UAV1, roster=ROSTER)
    with pytest.raises(ValueError, match="both"):
        OnboardStack(af, uav_id="uav1", identity=UAV1)


def _hover_state(p: tuple[float, float, float]):  # type: ignore[no-untyped-def]
    from uavmpc.plant import VehicleState

    return VehicleState(0.0, np.array(p, float), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]),
                        np.zeros(3))


def test_key_files_readable_by_others_are_refused(tmp_path) -> None:
    path = tmp_path / "gcs.id"
    write_identity(GCS, path)
    assert os.stat(path).st_mode & 0o777 == 0o600
    got = load_identity(path)
    assert got.member_id == "gcs" and got.public_key == GCS.public_key
    with pytest.raises(FileExistsError):  # never overwrites a key
        write_identity(UAV1, path)
    shared = tmp_path / "swarm.key"
    shared.write_text(KEY.hex())
    for f in (path, shared):
        os.chmod(f, 0o644)
        with pytest.raises(ValueError, match=r"readable by others.*chmod 600"):
            (load_identity if f is path else load_key)(f)
        os.chmod(f, 0o600)
    assert load_key(shared) == KEY
    bad = tmp_path / "bad.id"
    bad.write_text("gcs nothex\n")
    os.chmod(bad, 0o600)
    with pytest.raises(ValueError, match="not an identity file"):
        load_identity(bad)
    assert "gcs" in repr(GCS) and GCS.private_key.hex() not in repr(GCS)


def test_roster_files_round_trip_and_name_their_errors(tmp_path) -> None:
    path = tmp_path / "roster.toml"
    path.write_text(ROSTER.to_toml())
    got = load_roster(path)
    assert dict(got) == dict(ROSTER)
    cases = {
        "": "needs at least one",
        '[members.uav1]\nrole = "pilot"\npublic_key = "' + "00" * 32 + '"\n': "role",
        '[members.uav1]\nrole = "uav"\npublic_key = "abc"\n': "public_key",
        '[members.uav1]\nrole = "uav"\n': "public_key",
        '[members."bad id!"]\nrole = "uav"\npublic_key = "' + "00" * 32 + '"\n': "member id",
        '[members.uav1]\nrole = "uav"\nkey = 1\npublic_key = "' + "00" * 32 + '"\n': "key",
        "[members\n": "invalid TOML",
    }
    for text, needle in cases.items():
        path.write_text(text)
        with pytest.raises(ValueError, match=needle):
            load_roster(path)


def test_command_sequence_numbers_increase_even_if_the_clock_goes_back() -> None:
    t = [10.0]
    signer = CommandSigner(SharedKey(KEY, "gcs"), clock=lambda: t[0])
    seqs = []
    for now in (10.0, 10.0, 9.0, 11.0):
        t[0] = now
        seqs.append(unseal(signer.seal(b"x", "c"), "c", SharedKey(KEY)).seq)
    assert seqs == sorted(set(seqs)) and seqs[-1] == 11_000_000
    assert time.time() > 0  # the default clock is the wall clock


@pytest.mark.realtime
def test_a_node_takes_missions_only_from_an_operator_and_only_once() -> None:
    """Over Zenoh on loopback: a forged, an unsigned, a replayed, a wrong-identity and a
    misaddressed mission are each refused and counted; the genuine one is flown."""
    import threading

    pytest.importorskip("zenoh")
    from uavmpc.comms.zenoh_link import ZenohTransport
    from uavmpc.drivers.node import Node
    from uavmpc.drivers.swarm import free_ports
    from uavmpc.plant import Airframe

    ports = free_ports(2)
    swarm = f"id{ports[0]}"
    eps = [f"tcp/127.0.0.1:{p}" for p in ports]
    node_tx = ZenohTransport("uav1", swarm=swarm, listen=[eps[0]])
    gcs_tx = ZenohTransport("gcs", swarm=swarm, listen=[eps[1]], connect=[eps[0]])
    node = Node("uav1", 5, Airframe.packaged("f550"), node_tx, start_m=(0.0, 0.0, 5.0),
                identity=UAV1, roster=ROSTER)
    states = gcs_tx.subscribe("uav1/state", maxlen=100_000)
    thread = threading.Thread(target=node.run, args=(9.0,), daemon=True)
    thread.start()
    try:
        deadline = time.time() + 5.0
        while not states.drain() and time.time() < deadline:
            time.sleep(0.05)
        gcs = CommandSigner(GCS)
        genuine = gcs.seal(MISSION, "uav1/mission")
        away = b'{"goto": [-20.0, 0.0, 5.0, 0.0]}'
        attacks = [
            away,  # unsigned
            seal(away, "uav1/mission", Identity.generate("gcs"), 2**60),  # forged
            CommandSigner(UAV2).seal(away, "uav1/mission"),  # a UAV, not an operator
            gcs.seal(away, "uav2/mission"),  # genuine, for another UAV
        ]
        gcs_tx.send("uav1", "mission", genuine)
        # ... and the genuine one recorded and replayed: whichever copy arrives second is
        # the replay
        for data in [*attacks, genuine]:
            gcs_tx.send("uav1", "mission", data)
            time.sleep(0.05)
        thread.join(timeout=600)  # its flight, after its kernels are loaded
        assert not thread.is_alive(), "the node's flight did not end within 600 s"
    finally:
        node.stop()
        thread.join(timeout=10)
        gcs_tx.close()
        node_tx.close()
    s = node.stats
    assert s.commands_rejected == {"unsigned": 1, "forged": 2, "not allowed": 1,
                                   "replayed": 1}
    assert s.missions_rejected == 5
    state = node.vehicle.plant.state()
    assert np.linalg.norm(state.position_m - [3.0, 0.0, 5.0]) < 0.5  # the genuine goal only


@pytest.mark.realtime
def test_keygen_and_the_mission_command_reach_a_node(tmp_path, capsys) -> None:
    """What a field team types: ``uavmpc keygen`` twice, a node with its identity and the
    roster, ``uavmpc mission`` sealed as the operator: the node flies it, refuses nothing."""
    import threading

    pytest.importorskip("zenoh")
    from uavmpc.apps.cli import main
    from uavmpc.comms.zenoh_link import ZenohTransport
    from uavmpc.drivers.node import Node
    from uavmpc.drivers.swarm import free_ports
    from uavmpc.plant import Airframe

    keys = tmp_path / "keys"
    assert main(["keygen", "gcs", "--role", "operator", "--dir", str(keys)]) == 0
    assert main(["keygen", "uav1", "--role", "uav", "--dir", str(keys)]) == 0
    assert main(["keygen", "uav1", "--role", "uav", "--dir", str(keys)]) == 2  # once only
    assert "already has a member 'uav1'" in capsys.readouterr().err
    roster = load_roster(keys / "roster.toml")
    assert {m: roster[m].role for m in roster} == {"gcs": "operator", "uav1": "uav"}
    (port,) = free_ports(1)
    swarm = f"cli{port}"
    tx = ZenohTransport("uav1", swarm=swarm, listen=[f"tcp/127.0.0.1:{port}"])
    node = Node("uav1", 1, Airframe.packaged("f550"), tx, start_m=(0.0, 0.0, 5.0),
                identity=load_identity(keys / "uav1.id"), roster=roster)
    thread = threading.Thread(target=node.run, args=(8.0,), daemon=True)
    thread.start()
    try:
        # the node subscribed to its missions when it was built: one sent before its first
        # tick waits in its queue
        argv = ["mission", "--to", "uav1", "--goto", "2", "0", "5", "0", "--swarm", swarm,
                "--connect", f"tcp/127.0.0.1:{port}"]
        assert main([*argv, "--identity-file", str(keys / "uav1.id")]) == 0  # a UAV's key
        assert main([*argv, "--identity-file", str(keys / "gcs.id")]) == 0
        # its 8 s flight, after its kernels are loaded (a loaded machine takes its time)
        thread.join(timeout=600)
        assert not thread.is_alive(), "the node's 8 s flight did not end within 600 s"
    finally:
        node.stop()
        thread.join(timeout=10)
        tx.close()
    assert node.stats.commands_rejected == {"not allowed": 1}
    state = node.vehicle.plant.state()
    assert np.linalg.norm(state.position_m - [2.0, 0.0, 5.0]) < 0.3


def test_keygen_without_the_auth_extra_names_it(tmp_path, capsys, monkeypatch) -> None:
    """Without cryptography installed, ``uavmpc keygen`` says which extra to install (it said
    "No module named 'cryptography'"), and writes nothing."""
    import sys

    from uavmpc.apps.cli import main

    for name in [m for m in sys.modules if m == "cryptography" or m.startswith("cryptography.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "cryptography", None)  # import cryptography → ImportError
    keys = tmp_path / "keys"
    assert main(["keygen", "gcs", "--role", "operator", "--dir", str(keys)]) == 2
    err = capsys.readouterr().err
    assert "uavmpc[auth]" in err and "No module named" not in err
    assert not keys.exists() or not any(keys.iterdir())

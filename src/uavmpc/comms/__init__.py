"""Communication between UAVs (SPEC §5.1): the prediction message, its wire format, transports."""

from uavmpc.comms.auth import load_key, sign, verify
from uavmpc.comms.link import Inbox, LinkStats, SimulatedLink, Transport
from uavmpc.comms.message import (
    SCHEMA_VERSION,
    InvalidMessageError,
    PredictionMessage,
    decode,
    encode,
    from_prediction,
    validate_on_receipt,
)
from uavmpc.comms.zenoh_link import Subscription, ZenohStats, ZenohTransport

__all__ = [
    "SCHEMA_VERSION",
    "Inbox",
    "InvalidMessageError",
    "LinkStats",
    "PredictionMessage",
    "SimulatedLink",
    "Subscription",
    "Transport",
    "ZenohStats",
    "ZenohTransport",
    "decode",
    "encode",
    "from_prediction",
    "load_key",
    "sign",
    "validate_on_receipt",
    "verify",
]

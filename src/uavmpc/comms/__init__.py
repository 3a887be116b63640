"""Communication between UAVs (SPEC §5.1): the prediction message, its wire format, transports."""

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

__all__ = [
    "SCHEMA_VERSION",
    "Inbox",
    "InvalidMessageError",
    "LinkStats",
    "PredictionMessage",
    "SimulatedLink",
    "Transport",
    "decode",
    "encode",
    "from_prediction",
    "validate_on_receipt",
]

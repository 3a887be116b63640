"""Flight logs as MCAP files with Foxglove schemas (JSON encoding), opened by Foxglove, the
``mcap`` CLI and the ``mcap`` Python reader.

Topics per UAV ``<id>``:

- ``/<id>/state``, ``/<id>/command``, ``/<id>/reference``: ``foxglove.PoseInFrame`` (world frame
  ``"world"``, ENU; heading as a yaw quaternion), at ``pose_rate_hz``.
- ``/<id>/prediction``: ``foxglove.PosesInFrame``, the 40 predicted poses, at each broadcast.
- ``/<id>/status``: ``uavmpc.UavStatus`` (velocity, z offset, avoidance flag, conflicts, limit
  excess of the virtual UAV), at ``pose_rate_hz``.
- ``/link``: ``uavmpc.LinkEvent`` for every message sent, delivered, dropped or rejected.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer

_POSE_SCHEMA = {
    "title": "foxglove.PoseInFrame",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"},
                                                        "nsec": {"type": "integer"}}},
        "frame_id": {"type": "string"},
        "pose": {"type": "object", "properties": {
            "position": {"type": "object", "properties": {
                "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}},
            "orientation": {"type": "object", "properties": {
                "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"},
                "w": {"type": "number"}}}}},
    },
}
_POSES_SCHEMA = {
    "title": "foxglove.PosesInFrame",
    "type": "object",
    "properties": {
        "timestamp": _POSE_SCHEMA["properties"]["timestamp"],
        "frame_id": {"type": "string"},
        "poses": {"type": "array", "items": _POSE_SCHEMA["properties"]["pose"]},
    },
}
_STATUS_SCHEMA = {
    "title": "uavmpc.UavStatus",
    "type": "object",
    "properties": {
        "t_s": {"type": "number"},
        "velocity_mps": {"type": "array", "items": {"type": "number"}},
        "command_velocity_mps": {"type": "array", "items": {"type": "number"}},
        "z_offset_m": {"type": "number"},
        "avoiding": {"type": "boolean"},
        "conflicts": {"type": "array", "items": {"type": "string"}},
        "limit_excess": {"type": "number"},
        "braking": {"type": "boolean"},
    },
}
_LINK_SCHEMA = {
    "title": "uavmpc.LinkEvent",
    "type": "object",
    "properties": {
        "t_s": {"type": "number"},
        "event": {"type": "string", "enum": ["sent", "delivered", "dropped", "rejected"]},
        "sender": {"type": "string"},
        "receiver": {"type": "string"},
        "stamp_s": {"type": "number"},
        "detail": {"type": "string"},
    },
}


def _stamp(t_s: float) -> dict[str, int]:
    ns = max(0, round(t_s * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _pose(p: Iterable[float], heading_rad: float) -> dict[str, Any]:
    x, y, z = (float(v) for v in p)
    half = 0.5 * float(heading_rad)
    return {"position": {"x": x, "y": y, "z": z},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(half), "w": math.cos(half)}}


class FlightRecorder:
    """Writes one run to an MCAP file. Use as a context manager, or call :meth:`close`."""

    def __init__(self, path: str | Path, uav_ids: Iterable[str], metadata: dict[str, str],
                 objects: Iterable[str] = ()) -> None:
        """``objects``: other things in the scene that only have a pose (``/<name>/state``),
        e.g. the ground vehicle carrying a landing deck."""
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = self.path.open("wb")
        self._w = Writer(self._fh, compression=CompressionType.ZSTD)
        self._w.start(profile="", library="uavmpc")
        schemas = {s["title"]: self._w.register_schema(s["title"], "jsonschema",
                                                       json.dumps(s).encode())
                   for s in (_POSE_SCHEMA, _POSES_SCHEMA, _STATUS_SCHEMA, _LINK_SCHEMA)}
        self._ch: dict[str, int] = {}
        for uav in uav_ids:
            for topic, schema in (("state", "foxglove.PoseInFrame"),
                                  ("command", "foxglove.PoseInFrame"),
                                  ("reference", "foxglove.PoseInFrame"),
                                  ("prediction", "foxglove.PosesInFrame"),
                                  ("status", "uavmpc.UavStatus")):
                name = f"/{uav}/{topic}"
                self._ch[name] = self._w.register_channel(name, "json", schemas[schema])
        for name in objects:
            self._ch[f"/{name}/state"] = self._w.register_channel(
                f"/{name}/state", "json", schemas["foxglove.PoseInFrame"])
        self._ch["/link"] = self._w.register_channel("/link", "json", schemas["uavmpc.LinkEvent"])
        self._w.add_metadata("run", {k: str(v) for k, v in metadata.items()})
        self._seq = 0

    def _add(self, topic: str, t_s: float, msg: dict[str, Any]) -> None:
        ns = max(0, round(t_s * 1e9))
        self._seq += 1
        self._w.add_message(self._ch[topic], log_time=ns, publish_time=ns,
                            data=json.dumps(msg, separators=(",", ":")).encode(),
                            sequence=self._seq)

    def pose(self, uav: str, topic: str, t_s: float, position: np.ndarray, heading: float) -> None:
        self._add(f"/{uav}/{topic}", t_s, {"timestamp": _stamp(t_s), "frame_id": "world",
                                           "pose": _pose(position, heading)})

    def prediction(self, uav: str, t_s: float, positions: np.ndarray,
                   headings: np.ndarray) -> None:
        poses = [_pose(p, h) for p, h in zip(positions.tolist(), headings.tolist(), strict=True)]
        self._add(f"/{uav}/prediction", t_s,
                  {"timestamp": _stamp(t_s), "frame_id": "world", "poses": poses})

    def status(self, uav: str, t_s: float, **fields: Any) -> None:
        self._add(f"/{uav}/status", t_s, {"t_s": t_s, **fields})

    def link(self, t_s: float, event: str, sender: str, receiver: str = "", stamp_s: float = 0.0,
             detail: str = "") -> None:
        self._add("/link", t_s, {"t_s": t_s, "event": event, "sender": sender,
                                 "receiver": receiver, "stamp_s": stamp_s, "detail": detail})

    def close(self) -> None:
        self._w.finish()
        self._fh.close()

    def __enter__(self) -> FlightRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_topics(path: str | Path) -> dict[str, list[dict[str, Any]]]:
    """All messages of an MCAP log, decoded, by topic (for tests and analysis)."""
    from mcap.reader import make_reader

    out: dict[str, list[dict[str, Any]]] = {}
    with Path(path).open("rb") as fh:
        for _schema, channel, message in make_reader(fh).iter_messages():
            out.setdefault(channel.topic, []).append(json.loads(message.data))
    return out

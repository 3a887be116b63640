"""Flight logs as MCAP files with Foxglove schemas (JSON encoding), opened by Foxglove, the
``mcap`` CLI and the ``mcap`` Python reader.

Topics per UAV ``<id>``:

- ``/<id>/state``, ``/<id>/command``, ``/<id>/reference``: ``foxglove.PoseInFrame`` (world frame
  ``"world"``, ENU; heading as a yaw quaternion), at ``pose_rate_hz``.
- ``/<id>/prediction``: ``foxglove.PosesInFrame``, the 40 predicted poses, at each broadcast.
- ``/<id>/status``: ``uavmpc.UavStatus`` (velocity, z offset, avoidance flag, conflicts, whom
  it yields to, whether it holds short, whom it takes for deaf, the ids its messages list as
  heard and the position uncertainty they state, limit excess of the virtual UAV), at
  ``pose_rate_hz``.
- ``/link``: ``uavmpc.LinkEvent`` for every message sent, delivered, dropped or rejected.

And for the whole flight:

- ``/scene``: ``foxglove.SceneUpdate``, the 3-D scene (:mod:`uavmpc.view.scene`: bodies,
  plans, desired trajectories, avoidance cylinders coloured by state, ground, geofence, car).
- ``/metrics``: ``uavmpc.Metrics``, plot-ready numbers (closest pair, and per UAV its z offset,
  limit excess, tracker fallbacks).

The Foxglove messages are declared with Foxglove's published JSON schemas, unchanged
(``uavmpc/data/foxglove``); the ``uavmpc.*`` ones with their own.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer

from uavmpc.view.scene import METRICS_SCHEMA, SCENE_SCHEMA, published_schema, stamp
from uavmpc.view.scene import pose as _pose

_STATUS_SCHEMA: dict[str, Any] = {
    "title": "uavmpc.UavStatus",
    "type": "object",
    "properties": {
        "t_s": {"type": "number"},
        "velocity_mps": {"type": "array", "items": {"type": "number"}},
        "command_velocity_mps": {"type": "array", "items": {"type": "number"}},
        "z_offset_m": {"type": "number"},
        "avoiding": {"type": "boolean"},
        "conflicts": {"type": "array", "items": {"type": "string"}},
        "yielding_to": {"type": "array", "items": {"type": "string"}},
        "holding": {"type": "boolean"},
        "deaf": {"type": "array", "items": {"type": "string"}},
        "heard": {"type": "array", "items": {"type": "string"}},
        "position_sigma_horizontal_m": {"type": "number"},
        "position_sigma_vertical_m": {"type": "number"},
        "limit_excess": {"type": "number"},
        "braking": {"type": "boolean"},
        # the safety argument's assumptions broken now (uavmpc.assumptions)
        "broken": {"type": "array", "items": {"type": "string"}},
    },
}
_LINK_SCHEMA: dict[str, Any] = {
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


class FlightRecorder:
    """Writes one run to an MCAP file. Use as a context manager, or call :meth:`close`."""

    def __init__(self, path: str | Path, uav_ids: Iterable[str], metadata: Mapping[str, object],
                 objects: Iterable[str] = ()) -> None:
        """``metadata``: written as strings. ``objects``: other things in the scene that only
        have a pose (``/<name>/state``), e.g. the ground vehicle carrying a landing deck."""
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = self.path.open("wb")
        self._w = Writer(self._fh, compression=CompressionType.ZSTD)
        self._w.start(profile="", library="uavmpc")
        schemas = {s["title"]: self._w.register_schema(s["title"], "jsonschema",
                                                       json.dumps(s).encode())
                   for s in (_STATUS_SCHEMA, METRICS_SCHEMA, _LINK_SCHEMA)}
        for name in ("foxglove.PoseInFrame", "foxglove.PosesInFrame", SCENE_SCHEMA):
            schemas[name] = self._w.register_schema(name, "jsonschema",
                                                    published_schema(name).encode())
        self._ch: dict[str, int] = {}
        for uav in uav_ids:
            for topic, schema in (("state", "foxglove.PoseInFrame"),
                                  ("command", "foxglove.PoseInFrame"),
                                  ("reference", "foxglove.PoseInFrame"),
                                  # where a simulator says the vehicle truly is
                                  ("truth", "foxglove.PoseInFrame"),
                                  ("prediction", "foxglove.PosesInFrame"),
                                  ("status", "uavmpc.UavStatus")):
                name = f"/{uav}/{topic}"
                self._ch[name] = self._w.register_channel(name, "json", schemas[schema])
        for name in objects:
            self._ch[f"/{name}/state"] = self._w.register_channel(
                f"/{name}/state", "json", schemas["foxglove.PoseInFrame"])
        self._ch["/link"] = self._w.register_channel("/link", "json", schemas["uavmpc.LinkEvent"])
        self._ch["/scene"] = self._w.register_channel("/scene", "json", schemas[SCENE_SCHEMA])
        self._ch["/metrics"] = self._w.register_channel("/metrics", "json",
                                                        schemas["uavmpc.Metrics"])
        self._w.add_metadata("run", {k: str(v) for k, v in metadata.items()})
        self._seq = 0

    def _add(self, topic: str, t_s: float, msg: dict[str, Any]) -> None:
        ns = max(0, round(t_s * 1e9))
        self._seq += 1
        self._w.add_message(self._ch[topic], log_time=ns, publish_time=ns,
                            data=json.dumps(msg, separators=(",", ":")).encode(),
                            sequence=self._seq)

    def pose(self, uav: str, topic: str, t_s: float, position: np.ndarray, heading: float) -> None:
        self._add(f"/{uav}/{topic}", t_s, {"timestamp": stamp(t_s), "frame_id": "world",
                                           "pose": _pose(position, heading)})

    def prediction(self, uav: str, t_s: float, positions: np.ndarray,
                   headings: np.ndarray) -> None:
        poses = [_pose(p, h) for p, h in zip(positions.tolist(), headings.tolist(), strict=True)]
        self._add(f"/{uav}/prediction", t_s,
                  {"timestamp": stamp(t_s), "frame_id": "world", "poses": poses})

    def scene(self, t_s: float, update: dict[str, Any]) -> None:
        """A ``foxglove.SceneUpdate`` (:func:`uavmpc.view.scene.scene_update`)."""
        self._add("/scene", t_s, update)

    def metrics(self, t_s: float, numbers: dict[str, Any]) -> None:
        """The plot-ready numbers of now (``uavmpc.Metrics``)."""
        self._add("/metrics", t_s, numbers)

    def status(self, uav: str, t_s: float, **fields: object) -> None:
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

"""``uavmpc export-bag RUN_DIR``: a run's ``flight.mcap`` as a rosbag2 (MCAP storage, ROS 2
message types in CDR) that ``ros2 bag play`` and Foxglove open.

Topics (per UAV): ``/<id>/pose``, ``/<id>/command``, ``/<id>/reference``
(geometry_msgs/PoseStamped), ``/<id>/prediction`` (nav_msgs/Path, each point stamped along the
tracker's horizon), ``/<id>/avoidance`` (uavmpc_msgs/AvoidanceStatus, whose definition ships in
``data/msg/``; a machine playing the bag needs that package built to decode it). The link's
events have no standard ROS type and stay in ``flight.mcap``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc.comms.ros2 import AVOIDANCE_STATUS, PATH, POSE, Ros2Codec
from uavmpc.tracker import TrackerConfig

__all__ = ["export_bag"]

#: flight.mcap channel → (bag topic, ROS type)
_TOPICS = {"state": ("pose", POSE), "command": ("command", POSE),
           "reference": ("reference", POSE), "prediction": ("prediction", PATH),
           "status": ("avoidance", AVOIDANCE_STATUS)}


class BagExportError(ValueError):
    """The run folder has no readable flight log, or the bag folder cannot be written."""


def export_bag(run_dir: str | Path, out: str | Path | None = None, *,
               overwrite: bool = False) -> dict[str, Any]:
    """Write ``run_dir/flight.mcap`` as a rosbag2 folder (default ``run_dir/rosbag2``);
    returns its summary (path, messages per topic, time range)."""
    try:
        from mcap.reader import make_reader
        from rosbags.rosbag2 import StoragePlugin, Writer
    except ImportError:
        raise ImportError("export-bag needs rosbags: pip install 'uavmpc[ros2]'") from None
    run = Path(run_dir)
    log = run / "flight.mcap"
    if not log.is_file():
        raise BagExportError(f"{run}: no flight.mcap (write one with uavmpc run or swarm)")
    bag = Path(out) if out is not None else run / "rosbag2"
    if bag.exists():
        if not overwrite:
            raise BagExportError(f"{bag} exists (pass --overwrite to replace it)")
        shutil.rmtree(bag)
    codec = Ros2Codec()
    cfg = TrackerConfig()
    horizon = cfg.step_s * np.arange(cfg.steps)
    counts: dict[str, int] = {}
    t_first, t_last = None, None
    with log.open("rb") as fh, Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns: dict[str, Any] = {}
        try:
            messages = list(make_reader(fh).iter_messages())
        except Exception as exc:  # the mcap reader raises its own errors on a damaged file
            raise BagExportError(f"{log}: not a readable MCAP file ({exc})") from None
        for _schema, channel, message in messages:
            parts = channel.topic.strip("/").split("/")
            if len(parts) != 2 or parts[1] not in _TOPICS:
                continue
            uav, kind = parts
            topic, ros_type = _TOPICS[kind]
            name = f"/{uav}/{topic}"
            if name not in conns:
                conns[name] = w.add_connection(name, ros_type, typestore=codec.store)
            data = json.loads(message.data)
            t_s = message.log_time * 1e-9
            w.write(conns[name], message.log_time, _convert(codec, kind, data, t_s, horizon))
            counts[name] = counts.get(name, 0) + 1
            t_first = message.log_time if t_first is None else min(t_first, message.log_time)
            t_last = message.log_time if t_last is None else max(t_last, message.log_time)
    return {"bag": str(bag), "messages": counts, "start_ns": t_first, "end_ns": t_last}


def _pose_of(data: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    p, o = data["position"], data["orientation"]
    return (np.array([p["x"], p["y"], p["z"]], dtype=float),
            np.array([o["w"], o["x"], o["y"], o["z"]], dtype=float))


def _convert(codec: Ros2Codec, kind: str, data: dict[str, Any], t_s: float,
             horizon: np.ndarray) -> bytes:
    if kind in ("state", "command", "reference"):
        return codec.pose_stamped(t_s, *_pose_of(data["pose"]))
    if kind == "prediction":
        poses = [_pose_of(p) for p in data["poses"]]
        positions = np.array([p for p, _ in poses]).reshape(-1, 3)
        headings = np.array([2.0 * np.arctan2(q[3], q[0]) for _, q in poses])
        times = t_s + horizon[:len(poses)]
        return codec.path(t_s, times, positions, headings)
    # A flight log's status holds the decision's avoiding, offset, conflicts and yielding
    # (from the world's stacks, or a swarm's NodeState): the other fields take their defaults
    # unless a log carries them.
    return codec.avoidance_status(t_s, bool(data.get("avoiding", False)),
                                  float(data.get("z_offset_m", 0.0)),
                                  list(data.get("yielding_to", [])),
                                  heard=list(data.get("heard", [])),
                                  position_sigma_horizontal_m=float(
                                      data.get("position_sigma_horizontal_m", 0.0)),
                                  position_sigma_vertical_m=float(
                                      data.get("position_sigma_vertical_m", 0.0)),
                                  holding=bool(data.get("holding", False)),
                                  deaf=list(data.get("deaf", [])),
                                  broken=list(data.get("broken", [])))

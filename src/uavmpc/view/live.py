"""The live view: the scene and the metrics of a flight served to Foxglove while it flies, on a
Foxglove WebSocket server on localhost (the ``viz`` extra: ``pip install 'uavmpc[viz]'``).

Open Foxglove, "Open connection", ``ws://localhost:8765`` (the default port), and import the
layout ``docs/foxglove_layout.json`` for the 3-D panel, the plots and the avoidance table.

The channels are those of a log file (:mod:`uavmpc.log`), in the same JSON encoding and with
the same schemas: ``/scene`` (``foxglove.SceneUpdate``) and ``/metrics`` (``uavmpc.Metrics``).
Publishing never blocks the flight: the server keeps a bounded backlog per client and drops
the oldest when a client is slow; clients may connect late or leave at any time.
"""

from __future__ import annotations

import json
from types import ModuleType
from typing import Any

from uavmpc.view.scene import METRICS_SCHEMA, SCENE_SCHEMA, published_schema

#: The port Foxglove's WebSocket connection proposes by default.
DEFAULT_PORT = 8765
#: Messages buffered per client before the oldest are dropped (a slow client loses frames,
#: the flight loses nothing).
BACKLOG = 256

def _sdk() -> ModuleType:
    try:
        import foxglove
    except ImportError:
        raise ImportError("the live view needs the viz extra: pip install 'uavmpc[viz]'"
                          ) from None
    return foxglove


class LiveView:
    """A Foxglove WebSocket server on ``host:port`` serving ``/scene`` and ``/metrics``.

    ``port`` 0 takes a free one (:attr:`port` says which). Use as a context manager, or call
    :meth:`close`."""

    def __init__(self, *, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 name: str = "uavmpc") -> None:
        if not (isinstance(port, int) and 0 <= port <= 65535):
            raise ValueError(f"port: must be an integer in [0, 65535], got {port!r}")
        fg = _sdk()
        self._context = fg.Context()  # our channels only, not the process-wide ones
        try:
            self._server = fg.start_server(name=name, host=host, port=port,
                                           context=self._context,
                                           message_backlog_size=BACKLOG)
        except Exception as exc:  # the SDK raises its own error type for a busy port
            raise OSError(f"live view: cannot serve on {host}:{port}: {exc}") from None
        self.port: int = int(self._server.port)
        self.host = host
        self._scene = fg.Channel(
            "/scene", message_encoding="json", context=self._context,
            schema=fg.Schema(name=SCENE_SCHEMA, encoding="jsonschema",
                             data=published_schema(SCENE_SCHEMA).encode()))
        self._metrics = fg.Channel(
            "/metrics", message_encoding="json", context=self._context,
            schema=fg.Schema(name="uavmpc.Metrics", encoding="jsonschema",
                             data=json.dumps(METRICS_SCHEMA).encode()))
        self.published = 0

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def publish(self, t_s: float, scene: dict[str, Any], metrics: dict[str, Any]) -> None:
        """One snapshot (scene and metrics at ``t_s`` [s] of the flight's clock)."""
        ns = max(0, round(t_s * 1e9))
        self._scene.log(json.dumps(scene, separators=(",", ":")).encode(), log_time=ns)
        self._metrics.log(json.dumps(metrics, separators=(",", ":")).encode(), log_time=ns)
        self.published += 1

    def close(self) -> None:
        self._server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

"""``gcs view``: the team's scene live over the Foxglove WebSocket protocol (issue 29).

An operator opens Foxglove, connects to ``ws://HOST:PORT`` and watches the team fly. The
server is the ``foxglove-sdk`` package's (the protocol's reference implementation,
https://docs.foxglove.dev/docs/sdk); it serves, JSON-encoded with JSON Schemas:

* ``scene/transforms`` and ``scene/team``: the same ``foxglove.FrameTransforms`` and
  ``foxglove.SceneUpdate`` a recording holds (:mod:`groundstation.gcs.foxglove_scene`): true
  poses (in simulation), each vehicle's estimate of its pose in the team's frame, the sensing
  edges coloured by rigidity weight, camera frusta, alarms on the labels;
* every vehicle's ``status``, ``truth`` and ``camera/bearings`` under its Zenoh key, with the
  schemas of ``gcs record`` (:mod:`groundstation.gcs.schemas`), so Foxglove plots the scale
  estimate or the rigidity eigenvalue live; peer traffic (an envelope of every kind, 50 Hz
  per vehicle) is left out;
* the active alarms as the server's status messages (Foxglove's problems list), one per
  vehicle, removed when they clear.

It subscribes to Zenoh exactly as ``gcs monitor`` and ``gcs record`` do: the daemons publish
what they publish anyway, the view costs them nothing.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

import msgspec

from groundstation.gcs import schemas
from groundstation.gcs.foxglove_scene import (
    FRAME_TRANSFORMS_SCHEMA,
    SCENE_SCHEMA_NAME,
    SCENE_TOPIC,
    SCENE_UPDATE_SCHEMA,
    TRANSFORMS_SCHEMA_NAME,
    TRANSFORMS_TOPIC,
    SceneBuilder,
)
from messages.agent import VehicleStatus
from messages.keys import STATUS_TOPIC
from messages.sim import CAMERA_TOPIC, TRUTH_TOPIC

FORWARDED_TOPICS = (STATUS_TOPIC, TRUTH_TOPIC, CAMERA_TOPIC)
"""Per-vehicle topics the view serves besides the scene (``bf/<fleet>/<id>/<topic>``)."""
DEFAULT_PORT = 8765
"""Foxglove's default WebSocket port."""
_json = msgspec.json.Encoder()


def forwarded(key: str) -> bool:
    parts = key.split("/", 3)
    return len(parts) == 4 and parts[3] in FORWARDED_TOPICS


@dataclass
class LiveView:
    """A Foxglove WebSocket server fed by :meth:`zenoh_sample` (a ``ZenohListener`` hook)."""

    fleet: str
    scene: SceneBuilder = field(default_factory=SceneBuilder)
    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    """0: a free port (read :attr:`port` back after :meth:`start`)."""
    _server: Any = None
    _context: Any = None
    _channels: dict[tuple[str, str], Any] = field(default_factory=dict)
    _alarms: dict[int, tuple[str, ...]] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    counts: dict[str, int] = field(default_factory=dict)

    def start(self) -> LiveView:
        import foxglove

        self._context = foxglove.Context()
        self._server = foxglove.start_server(
            name=f"bearingflock {self.fleet}",
            host=self.host,
            port=self.port,
            context=self._context,
        )
        self.port = int(self._server.port)
        return self

    def _channel(self, topic: str, schema_name: str, schema: bytes) -> Any:
        ch = self._channels.get((topic, schema_name))
        if ch is None:
            import foxglove

            ch = foxglove.Channel(
                topic,
                schema=foxglove.Schema(
                    name=schema_name, encoding=schemas.SCHEMA_ENCODING, data=schema
                ),
                message_encoding=schemas.JSON_ENCODING,
                context=self._context,
            )
            self._channels[(topic, schema_name)] = ch
        return ch

    def _log(self, topic: str, schema: tuple[str, bytes], body: bytes, t_ns: int) -> None:
        self._channel(topic, *schema).log(body, log_time=t_ns)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def zenoh_sample(self, key: str, data: bytes, t_wall_s: float) -> None:
        """Fold one Zenoh sample in; serve it (forwarded topics) and the scene when due."""
        payload, _reason = schemas.decode_sample(data)
        if payload is None:
            return  # counted by the listener's state; nothing to draw
        t_ns = int(t_wall_s * 1e9)
        with self._lock:
            if self._server is None:
                return
            if forwarded(key):
                cls = type(payload)
                schema = (schemas.payload_schema_name(cls), schemas.payload_schema(cls))
                self._log(key, schema, schemas.payload_json(payload), t_ns)
            if isinstance(payload, VehicleStatus):
                self._status_alarms(payload)
            self.scene.add(payload, t_ns)
            msgs = self.scene.messages(t_ns)
            if msgs is not None:
                tfs, update = msgs
                schema = (TRANSFORMS_SCHEMA_NAME, FRAME_TRANSFORMS_SCHEMA)
                self._log(TRANSFORMS_TOPIC, schema, _json.encode(tfs), t_ns)
                self._log(SCENE_TOPIC, (SCENE_SCHEMA_NAME, SCENE_UPDATE_SCHEMA),
                          _json.encode(update), t_ns)  # fmt: skip

    def _status_alarms(self, status: VehicleStatus) -> None:
        """One status message per vehicle with alarms (Foxglove's problems list)."""
        import foxglove

        alarms = tuple(status.alarms)
        if self._alarms.get(status.sender, ()) == alarms:
            return
        self._alarms[status.sender] = alarms
        ident = f"alarms/{status.sender}"
        if alarms:
            self._server.publish_status(
                f"vehicle {status.sender}: {' '.join(alarms)}",
                foxglove.StatusLevel.Warning,
                ident,
            )
        else:
            self._server.remove_status([ident])

    def close(self) -> None:
        with self._lock:
            if self._server is not None:
                self._server.stop()
                self._server = None

"""Derived channels in Foxglove's own schemas, so Foxglove's 3D panel shows the team.

Two channels, JSON-encoded, named after Foxglove's message schemas (documented at
https://docs.foxglove.dev/docs/visualization/message-schemas/frame-transforms and
.../scene-update; the JSON Schemas below are written for the fields used here, with the same
names, types and nesting as Foxglove's published ones):

* :data:`TRANSFORMS_TOPIC` (``foxglove.FrameTransforms``): a fixed ``world`` frame (ENU, z up, as
  Foxglove draws), the ``ned`` frame under it (north-east-down, the project's frame), and under
  ``ned`` one frame per vehicle: ``truth/<id>`` (the simulator's truth, when recorded) and
  ``estimate/<id>`` (the agent's own ``(phat_i, psihat_i)``). Bearings fix the team only up to
  translation, scale and heading (paper 000), so with truth the estimates are drawn after the
  best similarity that maps them onto it (``similarity.similarity_2d``, Umeyama 1991); without
  truth they are drawn as estimated.
* :data:`SCENE_TOPIC` (``foxglove.SceneUpdate``): a sphere and a label per vehicle (truth: blue,
  estimate: orange; the label names the vehicle's active alarms and turns red with them), each
  vehicle's camera frustum (its sensing model's cone, :data:`FRUSTUM_LENGTH_M` long; a ring for
  an all-round camera), and the sensing edges, one line per camera detection ``i -> j`` seen in
  the last :data:`EDGE_MAX_AGE_S`, coloured by its rigidity weight ``w_ij = w_range w_fov``
  (paper 003 eq. 17-18, :func:`onboard.rigidity.weights.edge_weights` on the drawn poses): green
  at 1, yellow at 0.5, red at 0 (about to be lost); opaque when both ends see each other, faint
  when only one does.

:class:`SceneBuilder` is pure: fold payloads in with :meth:`SceneBuilder.add`, take both messages
with :meth:`SceneBuilder.messages` (at most every ``period_s`` of log time).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from groundstation.gcs.similarity import similarity_2d
from messages.agent import VehicleStatus
from messages.codec import Payload
from messages.sim import CameraBearings, Truth
from onboard.daemon.config import RigiditySection
from onboard.rigidity.weights import SensingModel, edge_weights

TRANSFORMS_TOPIC = "scene/transforms"
SCENE_TOPIC = "scene/team"
TRANSFORMS_SCHEMA_NAME = "foxglove.FrameTransforms"
SCENE_SCHEMA_NAME = "foxglove.SceneUpdate"
WORLD_FRAME = "world"
NED_FRAME = "ned"
EDGE_MAX_AGE_S = 1.0
SCENE_PERIOD_S = 0.1
_SQRT_HALF = math.sqrt(0.5)
NED_IN_ENU = {"x": _SQRT_HALF, "y": _SQRT_HALF, "z": 0.0, "w": 0.0}
"""Rotation of the NED axes in the ENU world: x_ned = y_enu, y_ned = x_enu, z_ned = -z_enu."""

TRUTH_COLOR = {"r": 0.2, "g": 0.5, "b": 1.0, "a": 1.0}
ESTIMATE_COLOR = {"r": 1.0, "g": 0.6, "b": 0.1, "a": 0.9}
ALARM_COLOR = {"r": 1.0, "g": 0.15, "b": 0.1, "a": 1.0}
FRUSTUM_COLOR = {"r": 0.5, "g": 0.8, "b": 1.0, "a": 0.5}
EDGE_BOTH_ALPHA = 0.95
EDGE_ONE_ALPHA = 0.4
FRUSTUM_LENGTH_M = 2.0
"""Drawn length of a camera frustum (its range, often tens of metres, would hide the team)."""
FRUSTUM_RAYS = 8
DEFAULT_CAMERA = SensingModel(RigiditySection().fov_deg, RigiditySection().range_m)
"""The daemons' default sensing model (fleet file ``[rigidity] fov_deg, range_m``)."""


def weight_color(w: float, alpha: float) -> dict[str, float]:
    """Red at rigidity weight 0, yellow at 0.5, green at 1."""
    w = min(1.0, max(0.0, w))
    return {"r": min(1.0, 2.0 * (1.0 - w)), "g": min(1.0, 2.0 * w), "b": 0.1, "a": alpha}


# --- JSON Schemas (Foxglove's names and layout, fields used here) ---------------------------------
def _obj(title: str, props: dict[str, Any], required: list[str] | None = None) -> dict[str, Any]:
    return {
        "title": title,
        "type": "object",
        "properties": props,
        "required": list(props) if required is None else required,
    }


_NUM = {"type": "number"}
_TIME = _obj(
    "time",
    {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0,
                                                         "maximum": 999_999_999}},
)  # fmt: skip
_DURATION = _obj(
    "duration", {"sec": {"type": "integer"}, "nsec": {"type": "integer", "minimum": 0}}
)
_VEC3 = _obj("foxglove.Vector3", {"x": _NUM, "y": _NUM, "z": _NUM})
_POINT3 = _obj("foxglove.Point3", {"x": _NUM, "y": _NUM, "z": _NUM})
_QUAT = _obj("foxglove.Quaternion", {"x": _NUM, "y": _NUM, "z": _NUM, "w": _NUM})
_POSE = _obj("foxglove.Pose", {"position": _VEC3, "orientation": _QUAT})
_COLOR = _obj("foxglove.Color", {"r": _NUM, "g": _NUM, "b": _NUM, "a": _NUM})
_FRAME_TRANSFORM = _obj(
    "foxglove.FrameTransform",
    {
        "timestamp": _TIME,
        "parent_frame_id": {"type": "string"},
        "child_frame_id": {"type": "string"},
        "translation": _VEC3,
        "rotation": _QUAT,
    },
)
_SPHERE = _obj("foxglove.SpherePrimitive", {"pose": _POSE, "size": _VEC3, "color": _COLOR})
_LINE = _obj(
    "foxglove.LinePrimitive",
    {
        "type": {"type": "integer", "enum": [0, 1, 2]},  # LINE_STRIP, LINE_LOOP, LINE_LIST
        "pose": _POSE,
        "thickness": _NUM,
        "scale_invariant": {"type": "boolean"},
        "points": {"type": "array", "items": _POINT3},
        "color": _COLOR,
        "colors": {"type": "array", "items": _COLOR},
        "indices": {"type": "array", "items": {"type": "integer", "minimum": 0}},
    },
)
_TEXT = _obj(
    "foxglove.TextPrimitive",
    {
        "pose": _POSE,
        "billboard": {"type": "boolean"},
        "font_size": _NUM,
        "scale_invariant": {"type": "boolean"},
        "color": _COLOR,
        "text": {"type": "string"},
    },
)
_ENTITY = _obj(
    "foxglove.SceneEntity",
    {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "id": {"type": "string"},
        "lifetime": _DURATION,
        "frame_locked": {"type": "boolean"},
        "spheres": {"type": "array", "items": _SPHERE},
        "lines": {"type": "array", "items": _LINE},
        "texts": {"type": "array", "items": _TEXT},
    },
    required=["timestamp", "frame_id", "id", "lifetime", "frame_locked"],
)
_DELETION = _obj(
    "foxglove.SceneEntityDeletion",
    {"timestamp": _TIME, "type": {"type": "integer", "enum": [0, 1]}, "id": {"type": "string"}},
)
FRAME_TRANSFORMS_SCHEMA = json.dumps(
    {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        **_obj(
            TRANSFORMS_SCHEMA_NAME,
            {"transforms": {"type": "array", "items": _FRAME_TRANSFORM}},
        ),
    }
).encode()
SCENE_UPDATE_SCHEMA = json.dumps(
    {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        **_obj(
            SCENE_SCHEMA_NAME,
            {
                "deletions": {"type": "array", "items": _DELETION},
                "entities": {"type": "array", "items": _ENTITY},
            },
        ),
    }
).encode()


# --- building the messages -------------------------------------------------------------------------
def stamp(t_ns: int) -> dict[str, int]:
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


def yaw_quaternion(yaw_rad: float) -> dict[str, float]:
    """Rotation by ``yaw_rad`` about the z axis of the parent frame (NED: down, so clockwise
    seen from above, which is the project's yaw)."""
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw_rad / 2), "w": math.cos(yaw_rad / 2)}


def _transform(t_ns: int, parent: str, child: str, p: Any, q: dict[str, float]) -> dict:
    return {
        "timestamp": stamp(t_ns),
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
        "rotation": q,
    }


_IDENTITY_POSE = {
    "position": {"x": 0.0, "y": 0.0, "z": 0.0},
    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
}


def align_estimates(
    est: dict[int, tuple[np.ndarray, float]], truth: dict[int, tuple[np.ndarray, float]]
) -> dict[int, tuple[np.ndarray, float]]:
    """The estimates mapped onto the truth by the best horizontal similarity (scale applied
    to the height too, heights matched in the mean); unchanged when fewer than two vehicles
    have both, or the estimates are all at one point."""
    common = sorted(set(est) & set(truth))
    if len(common) < 2:
        return est
    src = np.array([est[i][0][:2] for i in common])
    dst = np.array([truth[i][0][:2] for i in common])
    try:
        s, r, t = similarity_2d(src, dst)
    except ValueError:
        return est
    rot = math.atan2(r[1, 0], r[0, 0])
    z_src = np.mean([est[i][0][2] for i in common])
    z_dst = np.mean([truth[i][0][2] for i in common])
    out = {}
    for i, (p, yaw) in est.items():
        xy = s * r @ p[:2] + t
        out[i] = (np.array([xy[0], xy[1], z_dst + s * (p[2] - z_src)]), yaw + rot)
    return out


@dataclass
class SceneBuilder:
    """The latest truth, estimate and detections of every vehicle, turned into Foxglove
    messages (see the module doc)."""

    period_s: float = SCENE_PERIOD_S
    camera: SensingModel = DEFAULT_CAMERA
    """The vehicles' sensing model: edge weights and frusta."""
    truth: dict[int, tuple[np.ndarray, float]] = field(default_factory=dict)
    estimate: dict[int, tuple[np.ndarray, float]] = field(default_factory=dict)
    alarms: dict[int, list[str]] = field(default_factory=dict)
    """Each vehicle's active alarms, from its latest status."""
    detections: dict[tuple[int, int], int] = field(default_factory=dict)
    """Log time (ns) of the latest camera detection of ``j`` by ``i``, by ``(i, j)``."""
    _last_ns: int | None = None

    def add(self, payload: Payload, t_ns: int) -> None:
        """Fold one decoded payload in (others than truth, status and bearings are ignored)."""
        if isinstance(payload, Truth):
            self.truth[payload.sender] = (np.array(payload.p_ned, dtype=float), payload.yaw_rad)
        elif isinstance(payload, VehicleStatus):
            a = payload.agent
            self.estimate[payload.sender] = (np.array(a.p_hat_ned, dtype=float), a.yaw_hat_rad)
            self.alarms[payload.sender] = list(payload.alarms)
        elif isinstance(payload, CameraBearings):
            for j in payload.targets:
                self.detections[(payload.sender, int(j))] = t_ns

    def due(self, t_ns: int) -> bool:
        return self._last_ns is None or t_ns - self._last_ns >= self.period_s * 1e9

    def messages(self, t_ns: int) -> tuple[dict, dict] | None:
        """``(FrameTransforms, SceneUpdate)`` at ``t_ns`` if one is due and there is anything
        to show, else ``None``."""
        if not self.due(t_ns) or not (self.truth or self.estimate):
            return None
        self._last_ns = t_ns
        shown = align_estimates(self.estimate, self.truth)
        tfs = [_transform(t_ns, WORLD_FRAME, NED_FRAME, (0.0, 0.0, 0.0), NED_IN_ENU)]
        entities = []
        for kind, poses, color in (
            ("truth", self.truth, TRUTH_COLOR),
            ("estimate", shown, ESTIMATE_COLOR),
        ):
            for i, (p, yaw) in sorted(poses.items()):
                frame = f"{kind}/{i}"
                tfs.append(_transform(t_ns, NED_FRAME, frame, p, yaw_quaternion(yaw)))
                alarms = self.alarms.get(i, []) if kind == "estimate" else []
                label = f"{kind} {i}" + (": " + " ".join(alarms) if alarms else "")
                entities.append(
                    _vehicle_entity(t_ns, frame, f"{kind} {i}", label, color, bool(alarms))
                )
        sensed = "truth" if self.truth else "estimate"
        for i in sorted(self.truth or shown):
            entities.append(_frustum_entity(t_ns, f"{sensed}/{i}", f"frustum {i}", self.camera))
        entities.append(self._edges_entity(t_ns, self.truth or shown))
        return {"transforms": tfs}, {"deletions": [], "entities": entities}

    def edge_weights(
        self, edges: list[tuple[int, int]], where: dict[int, tuple[np.ndarray, float]]
    ) -> np.ndarray:
        """Rigidity weight of each edge ``(i, j)`` at the poses ``where`` (paper 003 eq. 18)."""
        if not edges:
            return np.zeros(0)
        ids = sorted(where)
        index = {v: k for k, v in enumerate(ids)}
        p = np.array([where[v][0] for v in ids])
        yaw = np.array([where[v][1] for v in ids])
        e = np.array([(index[i], index[j]) for i, j in edges])
        return edge_weights(p, yaw, e, self.camera).w

    def _edges_entity(self, t_ns: int, where: dict[int, tuple[np.ndarray, float]]) -> dict:
        fresh = {e for e, t in self.detections.items() if t_ns - t <= EDGE_MAX_AGE_S * 1e9}
        drawn = [(i, j) for i, j in sorted(fresh) if i in where and j in where]
        points, colors = [], []
        for (i, j), w in zip(drawn, self.edge_weights(drawn, where), strict=True):
            for p in (where[i][0], where[j][0]):
                points.append({"x": float(p[0]), "y": float(p[1]), "z": float(p[2])})
            alpha = EDGE_BOTH_ALPHA if (j, i) in fresh else EDGE_ONE_ALPHA
            color = weight_color(float(w), alpha)
            colors += [color, color]
        line = {
            "type": 2,
            "pose": _IDENTITY_POSE,
            "thickness": 3.0,
            "scale_invariant": True,
            "points": points,
            "color": weight_color(0.0, EDGE_ONE_ALPHA),
            "colors": colors,
            "indices": [],
        }
        return _entity(t_ns, NED_FRAME, "edges", lines=[line])


def _entity(t_ns: int, frame: str, ident: str, **prims: list) -> dict:
    return {
        "timestamp": stamp(t_ns),
        "frame_id": frame,
        "id": ident,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": True,
        **prims,
    }


def _vehicle_entity(
    t_ns: int, frame: str, ident: str, label: str, color: dict, alarmed: bool = False
) -> dict:
    sphere = {"pose": _IDENTITY_POSE, "size": {"x": 0.6, "y": 0.6, "z": 0.6}, "color": color}
    text = {
        "pose": {"position": {"x": 0.0, "y": 0.0, "z": -0.8}, "orientation": _QUAT_ID},
        "billboard": True,
        "font_size": 14.0,
        "scale_invariant": True,
        "color": ALARM_COLOR if alarmed else color,
        "text": label,
    }
    return _entity(t_ns, frame, ident, spheres=[sphere], texts=[text])


def frustum_points_body(camera: SensingModel, length_m: float = FRUSTUM_LENGTH_M) -> list[dict]:
    """Line-list points of a camera's cone in the body frame (FRD, camera along body x):
    :data:`FRUSTUM_RAYS` rays at the half field of view and the ring joining their tips; for an
    all-round camera, the horizontal ring of radius ``length_m``."""
    phis = 2.0 * np.pi * np.arange(FRUSTUM_RAYS) / FRUSTUM_RAYS
    if camera.all_round:
        tips = [(length_m * math.cos(a), length_m * math.sin(a), 0.0) for a in phis]
        rays: list[tuple[float, float, float]] = []
    else:
        h = math.radians(camera.fov_deg) / 2.0
        tips = [
            (length_m * math.cos(h), length_m * math.sin(h) * math.cos(a),
             length_m * math.sin(h) * math.sin(a))
            for a in phis
        ]  # fmt: skip
        rays = [x for tip in tips for x in ((0.0, 0.0, 0.0), tip)]
    ring = [x for k in range(len(tips)) for x in (tips[k], tips[(k + 1) % len(tips)])]
    return [{"x": x, "y": y, "z": z} for x, y, z in rays + ring]


def _frustum_entity(t_ns: int, frame: str, ident: str, camera: SensingModel) -> dict:
    line = {
        "type": 2,
        "pose": _IDENTITY_POSE,
        "thickness": 1.5,
        "scale_invariant": True,
        "points": frustum_points_body(camera),
        "color": FRUSTUM_COLOR,
        "colors": [],
        "indices": [],
    }
    return _entity(t_ns, frame, ident, lines=[line])


_QUAT_ID = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}

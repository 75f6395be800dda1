"""Formation files: agents with poses and cameras, and optional explicit sensing edges.

The format is shared by ``bearingflock check``, the simulator's ``--layout FILE`` and the demo::

    name = "square"                # optional
    [camera]                       # optional default for every agent
    fov_deg = 90.0                 # full cone angle of the camera (body x axis)
    range_m = 25.0
    [[agent]]
    id = 1
    position_ned = [0.0, 0.0, -5.0]
    yaw_deg = 10.0                 # optional, default 0
    fov_deg = 120.0                # optional per-agent override (also range_m)
    velocity_body = [1.0, 0.0, 0.0]  # optional, used by the observability analysis
    [[edge]]                       # optional: "from" sees "to"
    from = 1
    to = 2

Sensing edges come from ``[[edge]]`` when given (``edge_source = "file"``), else from each
camera's field of view and range when a ``[camera]`` section or a per-agent camera is given
(``"camera"``: :func:`onboard.graph.formation_edges` computes them), else every agent sees every
other one (``"complete"``). :func:`load_formation` validates everything and raises
:class:`FormationError` with a one-line message that names the problem and its place.
This module only parses and validates: no geometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np
from numpy.typing import NDArray

COINCIDENT_TOLERANCE_M = 1e-6
EdgeSource = Literal["file", "camera", "complete"]
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class FormationError(ValueError):
    """An invalid formation file; the message names the problem and where it is."""


class CameraSpec(msgspec.Struct, forbid_unknown_fields=True):
    fov_deg: float = 90.0
    range_m: float = 25.0


class AgentSpec(msgspec.Struct, forbid_unknown_fields=True):
    id: int
    position_ned: tuple[float, float, float]
    yaw_deg: float = 0.0
    fov_deg: float | None = None
    range_m: float | None = None
    velocity_body: tuple[float, float, float] | None = None


class EdgeSpec(msgspec.Struct, forbid_unknown_fields=True, rename={"from_": "from"}):
    from_: int
    to: int


class FormationFile(msgspec.Struct, forbid_unknown_fields=True):
    agent: list[AgentSpec]
    name: str = ""
    description: str = ""
    camera: CameraSpec | None = None
    edge: list[EdgeSpec] = msgspec.field(default_factory=list)


@dataclass(frozen=True)
class Formation:
    """A validated formation: arrays indexed by vertex ``0..N-1``; ``ids`` maps back to agent ids."""

    name: str
    ids: IntArray
    p_ned: FloatArray
    yaw_rad: FloatArray
    fov_deg: FloatArray
    range_m: FloatArray
    edge_source: EdgeSource
    edges_file: IntArray | None = None
    """Explicit ``[[edge]]`` list as vertex indices, when the file gives one."""
    velocity_body: FloatArray | None = None

    @property
    def n(self) -> int:
        return len(self.ids)

    def id_pairs(self, edges: IntArray) -> list[tuple[int, int]]:
        """Vertex-index edges as ``(from_id, to_id)`` pairs of agent ids."""
        return [(int(self.ids[i]), int(self.ids[j])) for i, j in edges]


def load_formation(path: str | Path) -> Formation:
    """Read and validate a formation file (see the module docstring for the format)."""
    path = Path(path)
    try:
        text = path.read_bytes()
    except OSError as exc:
        raise FormationError(f"{path}: cannot read file ({exc.strerror})") from None
    return parse_formation(text, source=str(path))


def parse_formation(text: bytes | str, source: str = "<formation>") -> Formation:
    """Validate formation TOML text; raise :class:`FormationError` naming the problem and place."""
    try:
        spec = msgspec.toml.decode(text, type=FormationFile)
    except msgspec.ValidationError as exc:
        raise FormationError(f"{source}: {_readable(str(exc))}") from None
    except msgspec.DecodeError as exc:
        raise FormationError(f"{source}: invalid TOML ({exc})") from None
    return _validate(spec, source)


def _readable(msg: str) -> str:
    """``Expected ... - at `$.agent[0].id``` -> ``agent[0].id: Expected ...``."""
    if " - at `$." in msg:
        what, where = msg.rsplit(" - at `$.", 1)
        return f"{where.rstrip('`')}: {what}"
    return msg


def _finite(values: tuple[float, ...] | float | None, where: str, source: str) -> None:
    if values is None:
        return
    seq = values if isinstance(values, tuple) else (values,)
    if not all(math.isfinite(v) for v in seq):
        raise FormationError(f"{source}: {where}: must be finite, got {values}")


def _validate(spec: FormationFile, source: str) -> Formation:
    if len(spec.agent) < 2:
        raise FormationError(f"{source}: agent: a formation needs at least 2 agents")
    camera = spec.camera or CameraSpec()
    _check_camera(camera.fov_deg, camera.range_m, "camera", source)
    ids: list[int] = []
    for k, a in enumerate(spec.agent):
        where = f"agent[{k}] (id {a.id})"
        if a.id < 0:
            raise FormationError(f"{source}: {where}.id: must be >= 0")
        if a.id in ids:
            raise FormationError(f"{source}: {where}.id: duplicate agent id {a.id}")
        ids.append(a.id)
        _finite(a.position_ned, f"{where}.position_ned", source)
        _finite(a.yaw_deg, f"{where}.yaw_deg", source)
        _finite(a.velocity_body, f"{where}.velocity_body", source)
        _check_camera(
            a.fov_deg if a.fov_deg is not None else camera.fov_deg,
            a.range_m if a.range_m is not None else camera.range_m,
            where,
            source,
        )
    p = np.array([a.position_ned for a in spec.agent], dtype=float)
    gaps = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1) + np.eye(len(p)) * 1e9
    i, j = np.unravel_index(np.argmin(gaps), gaps.shape)
    if gaps[i, j] < COINCIDENT_TOLERANCE_M:
        raise FormationError(
            f"{source}: agent[{i}] and agent[{j}]: coincident agents "
            f"(ids {ids[i]} and {ids[j]} at {p[i].tolist()})"
        )
    yaw = np.deg2rad([a.yaw_deg for a in spec.agent])
    fov = np.array([a.fov_deg if a.fov_deg is not None else camera.fov_deg for a in spec.agent])
    rng = np.array([a.range_m if a.range_m is not None else camera.range_m for a in spec.agent])
    index = {agent_id: k for k, agent_id in enumerate(ids)}
    source_kind: EdgeSource
    edges = None
    if spec.edge:
        pairs = []
        for k, e in enumerate(spec.edge):
            for end in (e.from_, e.to):
                if end not in index:
                    raise FormationError(f"{source}: edge[{k}]: unknown agent id {end}")
            if e.from_ == e.to:
                raise FormationError(f"{source}: edge[{k}]: agent {e.from_} cannot see itself")
            pairs.append((index[e.from_], index[e.to]))
        edges = np.unique(np.array(pairs, dtype=np.int64), axis=0)
        source_kind = "file"
    elif spec.camera is not None or any(
        a.fov_deg is not None or a.range_m is not None for a in spec.agent
    ):
        source_kind = "camera"
    else:
        source_kind = "complete"
    velocities = None
    if any(a.velocity_body is not None for a in spec.agent):
        missing = [a.id for a in spec.agent if a.velocity_body is None]
        if missing:
            raise FormationError(
                f"{source}: agent ids {missing}: velocity_body must be given for every agent or none"
            )
        velocities = np.array([a.velocity_body for a in spec.agent], dtype=float)
    return Formation(
        name=spec.name or Path(source).stem,
        ids=np.array(ids, dtype=np.int64),
        p_ned=p,
        yaw_rad=yaw,
        fov_deg=fov,
        range_m=rng,
        edge_source=source_kind,
        edges_file=edges,
        velocity_body=velocities,
    )


def _check_camera(fov_deg: float, range_m: float, where: str, source: str) -> None:
    _finite(fov_deg, f"{where}.fov_deg", source)
    _finite(range_m, f"{where}.range_m", source)
    if not 0.0 < fov_deg <= 360.0:
        raise FormationError(f"{source}: {where}.fov_deg: must be in (0, 360], got {fov_deg}")
    if range_m <= 0.0:
        raise FormationError(f"{source}: {where}.range_m: must be > 0, got {range_m}")

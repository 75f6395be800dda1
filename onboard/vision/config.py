"""Camera and marker files (TOML), validated into a :class:`CameraModel` and :class:`MarkerSpec` s.

Camera file (OpenCV pinhole model, optical axis = body x; keys beyond the first seven optional)::

    width = 640
    height = 480
    fx = 320.0
    fy = 320.0
    cx = 320.0
    cy = 240.0
    dist = [0.0, 0.0, 0.0, 0.0, 0.0]      # k1 k2 p1 p2 k3 (4 values: k3 = 0)
    mount_rpy_deg = [0.0, 0.0, 0.0]       # camera rotation from the forward mount, body axes
    t_body_cam_m = [0.0, 0.0, 0.0]        # camera centre in the body frame (FRD, m)

Markers file::

    [[marker]]
    id = 3                                 # vehicle that carries it
    kind = "tag"                           # or "disc"
    family = "apriltag_36h11"              # tags: OpenCV aruco dictionary name
    tag_id = 3                             # tags: id in the dictionary (default: id)
    size_m = 0.30                          # tag side (black square) or disc diameter
    color_hsv_min = [100, 150, 80]         # discs: OpenCV HSV (H 0-179), h_min > h_max wraps
    color_hsv_max = [130, 255, 255]

Errors raise :class:`VisionConfigError` with a one-line message naming the file and the problem.
"""

from __future__ import annotations

from pathlib import Path

import msgspec

from onboard.vision.camera import CameraModel
from onboard.vision.markers import MarkerSpec
from onboard.vision.tags import tag_families


class VisionConfigError(ValueError):
    """An invalid camera or markers file (one-line message)."""


class _CameraFile(msgspec.Struct, forbid_unknown_fields=True):
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: list[float] = msgspec.field(default_factory=lambda: [0.0] * 5)
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    t_body_cam_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = ""


class _MarkerEntry(msgspec.Struct, forbid_unknown_fields=True):
    id: int
    kind: str
    size_m: float
    family: str = "apriltag_36h11"
    tag_id: int | None = None
    color_hsv_min: tuple[int, int, int] | None = None
    color_hsv_max: tuple[int, int, int] | None = None
    name: str = ""


class _MarkersFile(msgspec.Struct, forbid_unknown_fields=True):
    marker: list[_MarkerEntry]


def _read(path: Path, kind: type) -> object:
    try:
        text = Path(path).read_bytes()
    except OSError as exc:
        raise VisionConfigError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        return msgspec.toml.decode(text, type=kind)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise VisionConfigError(f"{path}: {exc}") from None


def camera_from_dict(data: dict, where: str = "camera") -> CameraModel:
    """Validate a camera mapping (the TOML keys) into a :class:`CameraModel`."""
    try:
        f = msgspec.convert(data, _CameraFile)
    except msgspec.ValidationError as exc:
        raise VisionConfigError(f"{where}: {exc}") from None
    return _camera(f, where)


def _camera(f: _CameraFile, where: str) -> CameraModel:
    dist = list(f.dist)
    if len(dist) == 4:
        dist.append(0.0)
    if len(dist) != 5:
        raise VisionConfigError(f"{where}: dist needs 4 or 5 coefficients (k1 k2 p1 p2 [k3])")
    try:
        return CameraModel(
            width=f.width,
            height=f.height,
            fx=f.fx,
            fy=f.fy,
            cx=f.cx,
            cy=f.cy,
            dist=(dist[0], dist[1], dist[2], dist[3], dist[4]),
            mount_rpy_deg=f.mount_rpy_deg,
            t_body_cam_m=f.t_body_cam_m,
        )
    except ValueError as exc:
        raise VisionConfigError(f"{where}: {exc}") from None


def load_camera(path: str | Path) -> CameraModel:
    """Read a camera file; raises :class:`VisionConfigError`."""
    f = _read(Path(path), _CameraFile)
    assert isinstance(f, _CameraFile)
    return _camera(f, str(path))


def load_markers(path: str | Path) -> list[MarkerSpec]:
    """Read a markers file; raises :class:`VisionConfigError` naming the bad entry."""
    f = _read(Path(path), _MarkersFile)
    assert isinstance(f, _MarkersFile)
    families = tag_families()
    specs: list[MarkerSpec] = []
    seen: set[int] = set()
    for k, m in enumerate(f.marker):
        where = f"{path}: marker[{k}] (id {m.id})"
        if m.id in seen:
            raise VisionConfigError(f"{where}: vehicle id {m.id} has two markers")
        seen.add(m.id)
        if m.kind not in ("disc", "tag"):
            raise VisionConfigError(f"{where}: kind must be 'disc' or 'tag', got {m.kind!r}")
        if not m.size_m > 0.0:
            raise VisionConfigError(f"{where}: size_m must be positive")
        if m.kind == "tag" and m.family.lower() not in families:
            raise VisionConfigError(f"{where}: unknown tag family {m.family!r}")
        if m.kind == "disc":
            if m.color_hsv_min is None or m.color_hsv_max is None:
                raise VisionConfigError(f"{where}: discs need color_hsv_min and color_hsv_max")
            for name, hsv in (
                ("color_hsv_min", m.color_hsv_min),
                ("color_hsv_max", m.color_hsv_max),
            ):
                if not (0 <= hsv[0] <= 179 and 0 <= hsv[1] <= 255 and 0 <= hsv[2] <= 255):
                    raise VisionConfigError(f"{where}: {name} out of range (H 0-179, S/V 0-255)")
        specs.append(
            MarkerSpec(
                id=m.id,
                kind="disc" if m.kind == "disc" else "tag",
                size_m=m.size_m,
                family=m.family.lower(),
                tag_id=m.tag_id,
                color_hsv_min=m.color_hsv_min,
                color_hsv_max=m.color_hsv_max,
            )
        )
    tags = [(s.family, s.dictionary_id) for s in specs if s.kind == "tag"]
    if len(set(tags)) != len(tags):
        raise VisionConfigError(f"{path}: two markers share the same tag family and tag_id")
    return specs

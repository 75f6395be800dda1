"""Setpoints files for the landmark planner: TOML parsed by msgspec into typed Structs.

Format (local NED metres; see ``docs/planner.md``)::

    sigma_m = 0.1            # bearing noise (unit-vector components)
    prior_cov = 30.0         # prior covariance: scalar (times I) or a 3x3 list of rows, m^2
    r_min = 2.0              # no landmark closer than this to any setpoint, m
    r_max = 60.0             # every landmark within this distance of the origin, m
    # ground_down_m = 0.0    # optional: landmarks on the plane down = ground_down_m
    [[setpoint]]
    p = [0.0, 10.0, -5.0]    # north, east, down
    # heading_deg = 30.0     # optional, with --fov: fixed camera heading (yaw, 0 = north)

Any problem (bad TOML, a missing or unknown field, NaN, no setpoints, an infeasible
``r_min``/``r_max``) raises :class:`SetpointsError` with a one-line message.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import msgspec
import numpy as np

from groundstation.planner.problem import PlacementProblem, ProblemError, make_problem


class SetpointsError(ValueError):
    """The setpoints file cannot be used; the message names the problem in one line."""


class SetpointSpec(msgspec.Struct, forbid_unknown_fields=True):
    """One setpoint: position ``p`` (NED, m) and an optional camera heading (deg)."""

    p: Annotated[list[float], msgspec.Meta(min_length=3, max_length=3)]
    heading_deg: float | None = None


class SetpointsFile(msgspec.Struct, forbid_unknown_fields=True):
    """The whole file (see the module docstring)."""

    sigma_m: float
    prior_cov: float | list[list[float]]
    r_min: float
    r_max: float
    setpoint: list[SetpointSpec] = msgspec.field(default_factory=list)
    ground_down_m: float | None = None


def _check_finite(spec: SetpointsFile) -> None:
    for name in ("sigma_m", "r_min", "r_max", "ground_down_m"):
        value = getattr(spec, name)
        if value is not None and not math.isfinite(value):
            raise SetpointsError(f"{name} must be a finite number, got {value}")
    if not np.all(np.isfinite(np.asarray(spec.prior_cov, dtype=float))):
        raise SetpointsError("prior_cov must be finite")
    for i, sp in enumerate(spec.setpoint):
        if not all(math.isfinite(c) for c in sp.p):
            raise SetpointsError(f"setpoint {i}: p must be finite, got {sp.p}")
        if sp.heading_deg is not None and not math.isfinite(sp.heading_deg):
            raise SetpointsError(f"setpoint {i}: heading_deg must be finite")


def parse_setpoints(data: bytes | str, source: str = "<setpoints>") -> SetpointsFile:
    """Decode and check a setpoints TOML document; raises :class:`SetpointsError`."""
    try:
        spec = msgspec.toml.decode(data, type=SetpointsFile)
    except msgspec.ValidationError as exc:
        raise SetpointsError(f"{source}: {exc}") from None
    except msgspec.DecodeError as exc:
        raise SetpointsError(f"{source}: not valid TOML ({exc})") from None
    if not spec.setpoint:
        raise SetpointsError(f"{source}: no [[setpoint]] entries")
    try:
        _check_finite(spec)
    except SetpointsError as exc:
        raise SetpointsError(f"{source}: {exc}") from None
    return spec


def load_setpoints(path: str | Path) -> SetpointsFile:
    """Read and parse a setpoints file; a missing or unreadable file is a :class:`SetpointsError`."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SetpointsError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return parse_setpoints(data, str(path))


def problem_from_spec(
    spec: SetpointsFile,
    n_landmarks: int,
    fov_deg: float | None = None,
    source: str = "<setpoints>",
) -> PlacementProblem:
    """Build the placement problem; geometry errors become :class:`SetpointsError`."""
    setpoints = np.array([sp.p for sp in spec.setpoint], dtype=float)
    headings = None
    if any(sp.heading_deg is not None for sp in spec.setpoint):
        headings = [np.nan if sp.heading_deg is None else sp.heading_deg for sp in spec.setpoint]
    try:
        return make_problem(
            setpoints,
            n_landmarks,
            spec.sigma_m,
            spec.prior_cov,
            spec.r_min,
            spec.r_max,
            fov_deg=fov_deg,
            headings_deg=headings if fov_deg is not None else None,
            ground_down_m=spec.ground_down_m,
        )
    except ProblemError as exc:
        raise SetpointsError(f"{source}: {exc}") from None

"""Time series from a recording, and the errors the plots show.

:func:`load_series` reads an MCAP file written by ``gcs record`` into numpy arrays per agent
(statuses), per vehicle (simulator truth) and per camera (bearings); the error functions are
pure and vectorized:

* :func:`inverse_distance_error` — ``|chihat_ij - 1/d_ij|`` (1/m), the SfM observer's error on
  the inverse distance of a reciprocal edge (paper 000, eq. 8; its results count an edge
  converged below 0.01 1/m), with ``d_ij`` from the truth at the same time;
* :func:`bearing_errors_rad` — the angle between a measured body-frame bearing ``beta_ij`` and
  the one the estimates predict, ``R_z(psihat_i)^T (phat_j - phat_i) / |phat_j - phat_i|``
  (the R3 x S1 model of paper 000; invariant to the shared frame's translation, yaw and scale);
* the least-squares similarity that maps estimated horizontal positions onto the truth, to draw
  both trajectories on one set of axes, is :func:`groundstation.gcs.similarity.similarity_2d`.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from onboard.geometry import FloatArray, IntArray

if TYPE_CHECKING:
    from groundstation.gcs.record import Record

NO_INDEX = -1


@dataclass
class AgentSeries:
    """One agent's statuses: times (s since the recording's start) and estimates."""

    t_s: FloatArray
    p_hat_ned: FloatArray
    """(T, 3)"""
    yaw_hat_rad: FloatArray
    e_index: FloatArray
    lambda_bar: FloatArray
    rigidity: FloatArray
    """NaN where the agent did not report it."""
    chi_t_s: FloatArray
    """Flattened inverse-distance estimates: time, neighbour id and value of each."""
    chi_j: IntArray
    chi_inv_m: FloatArray


@dataclass
class TruthSeries:
    t_s: FloatArray
    p_ned: FloatArray
    yaw_rad: FloatArray


@dataclass
class BearingSeries:
    """One camera's detections, flattened: time, target id and body-frame unit bearing."""

    t_s: FloatArray
    target: IntArray
    beta_body: FloatArray


@dataclass
class Series:
    fleet: str
    agents: dict[int, AgentSeries] = field(default_factory=dict)
    truth: dict[int, TruthSeries] = field(default_factory=dict)
    bearings: dict[int, BearingSeries] = field(default_factory=dict)

    @property
    def vehicles(self) -> list[int]:
        return sorted(set(self.agents) | set(self.truth) | set(self.bearings))


# --- pure functions ----------------------------------------------------------------------------------
def latest_index(t_query: FloatArray, t_samples: FloatArray) -> IntArray:
    """Index of the latest sample at or before each query time (``NO_INDEX`` before the first);
    ``t_samples`` must be sorted."""
    return np.searchsorted(np.asarray(t_samples), np.asarray(t_query), side="right") - 1


def inverse_distance_error(
    t_s: FloatArray,
    chi_inv_m: FloatArray,
    p_i_ned: FloatArray,
    p_j_ned: FloatArray,
) -> FloatArray:
    """``|chi - 1/|p_j - p_i||`` row by row (1/m); ``t_s`` is only checked for shape."""
    d = np.linalg.norm(np.asarray(p_j_ned) - np.asarray(p_i_ned), axis=-1)
    if np.shape(t_s) != np.shape(chi_inv_m) or np.shape(d) != np.shape(chi_inv_m):
        raise ValueError("times, estimates and positions must have the same length")
    return np.abs(np.asarray(chi_inv_m) - 1.0 / d)


def predicted_bearings_body(
    p_i_ned: FloatArray, yaw_i_rad: FloatArray, p_j_ned: FloatArray
) -> FloatArray:
    """``R_z(yaw_i)^T (p_j - p_i) / |p_j - p_i|`` row by row, (M, 3)."""
    diff = np.asarray(p_j_ned, dtype=float) - np.asarray(p_i_ned, dtype=float)
    c, s = np.cos(yaw_i_rad), np.sin(yaw_i_rad)
    body = np.stack(
        [c * diff[:, 0] + s * diff[:, 1], -s * diff[:, 0] + c * diff[:, 1], diff[:, 2]], axis=1
    )
    return body / np.linalg.norm(body, axis=1, keepdims=True)


def angle_between_rad(a: FloatArray, b: FloatArray) -> FloatArray:
    """Angle between unit vectors row by row, accurate near 0 (``atan2(|a x b|, a . b)``)."""
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    return np.arctan2(cross, np.sum(np.asarray(a) * np.asarray(b), axis=-1))


def bearing_errors_rad(
    cam: BearingSeries,
    p_i_ned: FloatArray,
    yaw_i_rad: FloatArray,
    p_j_ned: FloatArray,
) -> FloatArray:
    """Angle between each measured bearing of ``cam`` and the predicted one, given per-row
    positions of the camera's vehicle and of its target (and the camera vehicle's yaw)."""
    return angle_between_rad(cam.beta_body, predicted_bearings_body(p_i_ned, yaw_i_rad, p_j_ned))


def rows_at(
    times: FloatArray, series_t: FloatArray, values: FloatArray
) -> tuple[np.ndarray, FloatArray]:
    """Values of a series at the latest sample before each time, and a mask of the valid rows."""
    idx = latest_index(times, series_t)
    ok = idx >= 0
    return ok, np.asarray(values)[np.where(ok, idx, 0)]


# --- loading -------------------------------------------------------------------------------------------
def load_series(
    path: str | Path, fleet: str | None = None, records: Iterable[Record] | None = None
) -> Series:
    """Decode a recording's statuses, truth and camera bearings into :class:`Series`.
    ``fleet=None`` takes the first fleet found in the recording; ``records``: the recording
    already read (``record.read_recording``), else ``path`` is read."""
    from groundstation.gcs.record import ZENOH_ENCODING, iter_records
    from groundstation.gcs.zenoh_listener import classify
    from messages.agent import VehicleStatus
    from messages.codec import MessageError
    from messages.sim import CameraBearings, Truth

    status: dict[int, list[tuple[float, VehicleStatus]]] = {}
    truth: dict[int, list[tuple[float, Truth]]] = {}
    cams: dict[int, list[tuple[float, CameraBearings]]] = {}
    t0: int | None = None
    for rec in iter_records(path) if records is None else records:
        if t0 is None:
            t0 = rec.log_time_ns
        if rec.encoding != ZENOH_ENCODING or not rec.topic.startswith("bf/"):
            continue
        if fleet is None:
            fleet = rec.topic.split("/")[1]
        try:
            d = classify(fleet, rec.topic, rec.data)
        except MessageError:
            continue
        t = (rec.log_time_ns - t0) / 1e9
        if d.agent_id is None:
            continue
        if isinstance(d.payload, VehicleStatus):
            status.setdefault(d.agent_id, []).append((t, d.payload))
        elif isinstance(d.payload, Truth):
            truth.setdefault(d.agent_id, []).append((t, d.payload))
        elif isinstance(d.payload, CameraBearings):
            cams.setdefault(d.agent_id, []).append((t, d.payload))
    out = Series(fleet or "?")
    for i, rows in status.items():
        out.agents[i] = _agent_series(rows)
    for i, rows in truth.items():
        out.truth[i] = TruthSeries(
            np.array([t for t, _ in rows]),
            np.array([m.p_ned for _, m in rows], dtype=float).reshape(-1, 3),
            np.array([m.yaw_rad for _, m in rows]),
        )
    for i, rows in cams.items():
        out.bearings[i] = BearingSeries(
            np.array([t for t, m in rows for _ in m.targets], dtype=float),
            np.array([j for _, m in rows for j in m.targets], dtype=int),
            np.array([b for _, m in rows for b in m.beta_body], dtype=float).reshape(-1, 3),
        )
    return out


def _agent_series(rows: list) -> AgentSeries:
    agents = [s.agent for _, s in rows]
    chi = [
        (t, j, x)
        for (t, _), a in zip(rows, agents, strict=True)
        for j, x in a.chi_hat_inv_m.items()
    ]
    return AgentSeries(
        t_s=np.array([t for t, _ in rows]),
        p_hat_ned=np.array([a.p_hat_ned for a in agents], dtype=float).reshape(-1, 3),
        yaw_hat_rad=np.array([a.yaw_hat_rad for a in agents]),
        e_index=np.array([a.e_index for a in agents]),
        lambda_bar=np.array([a.lambda_bar for a in agents]),
        rigidity=np.array(
            [np.nan if a.rigidity_eigenvalue is None else a.rigidity_eigenvalue for a in agents]
        ),
        chi_t_s=np.array([c[0] for c in chi], dtype=float),
        chi_j=np.array([c[1] for c in chi], dtype=int),
        chi_inv_m=np.array([c[2] for c in chi], dtype=float),
    )

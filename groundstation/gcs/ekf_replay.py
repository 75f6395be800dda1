"""Paper 001's centralized EKF on a recording: ``bearingflock gcs estimate --replay FILE.mcap``.

Reads the Zenoh samples a ``gcs record`` file holds (:func:`groundstation.gcs.record.read_recording`):
every vehicle's odometry (``peer.motion``: body velocity and yaw rate, :class:`messages.peer.MotionShare`)
and camera frames (``peer.bearings``: body-frame bearings, :class:`messages.peer.BearingShare`),
from its peer envelopes (:mod:`messages.envelope`; or single payloads, in older recordings),
and the simulator's ``truth`` when present (the sample nearest the final estimate's time). The vehicles are ``R^3 x S^1`` multicopters (the
bearings are levelled, the rates are yaw rates), a special case of the filter's ``SE(3)``
model with ``w = (0, 0, yaw rate)``. The vehicle with the lowest id is the reference (it moves:
relative kinematics, :mod:`onboard.estimation.se3_ekf`).

Processing, in the order of the samples' ``stamp_s``, by :class:`groundstation.gcs.ekf_loop.EkfLoop`
(the loop the live ``gcs estimate`` runs too, here with the team fixed): at each camera frame the filter predicts
from the previous frame with each vehicle's latest odometry (zero-order hold) and updates with
the frame's bearings. Bad input is counted and skipped: undecodable samples, bearings that are
not unit vectors or name a vehicle that never sent odometry, odometry older than ``stale_s``
(that vehicle's inputs are taken as zero for the step, with a growing uncertainty).

The prior knows nothing: the vehicles on a ring of radius ``prior_radius_m`` about the
reference, level, with standard deviations ``prior_sigma_p_m`` and ``prior_sigma_theta_rad``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from groundstation.gcs.ekf_loop import EkfLoop, EkfLoopConfig
from groundstation.gcs.record import ZENOH_ENCODING, read_recording
from groundstation.gcs.schemas import decode_payloads
from messages.peer import BearingShare, MotionShare
from messages.sim import Truth
from onboard.estimation.se3_ekf import Se3EkfState
from onboard.geometry import FloatArray, rot_z

ReplayConfig = EkfLoopConfig
"""Filter settings for a replay (the loop's; membership is fixed: nobody is dropped)."""

HISTORY_PERIOD_S = 0.1
"""The estimate is kept for ``gcs estimate --plot`` at most this often (recording time)."""


@dataclass(frozen=True)
class EstimateSample:
    """The estimate after one update: for the replay's figures."""

    t_s: float
    p_ref_m: FloatArray
    """``(N, 3)`` every vehicle's position in the reference's frame (the reference's is 0)."""
    sigma_p_m: FloatArray
    """``(N,)`` 1-sigma position radius, ``sqrt(trace)`` of its 3x3 covariance block (0 for the
    reference)."""


@dataclass
class ReplayResult:
    """What the replay found: the final estimate, the counters and, with truth, the errors."""

    ids: list[int]
    state: Se3EkfState | None
    frames: int = 0
    counts: dict[str, int] = field(default_factory=dict)
    duration_s: float = 0.0
    truth: dict[int, tuple[FloatArray, float]] = field(default_factory=dict)
    truth_age_s: float = 0.0
    """Largest time between the final estimate and the truth sample compared with it."""
    history: list[EstimateSample] = field(default_factory=list)
    """The estimate every :data:`HISTORY_PERIOD_S` (for the figures)."""
    truth_log: dict[int, list[tuple[float, FloatArray, float]]] = field(default_factory=dict)
    """Every truth sample of the recording: ``(stamp_s, p_ned, yaw_rad)`` per vehicle."""

    def true_distances(self, t_s: float) -> FloatArray | None:
        """``(P,)`` true pairwise distances (pairs as :meth:`pairs`) from the truth samples
        nearest ``t_s``; ``None`` without truth for every vehicle."""
        if not all(self.truth_log.get(i) for i in self.ids):
            return None
        p = np.array([min(self.truth_log[i], key=lambda s: abs(s[0] - t_s))[1] for i in self.ids])
        return np.array([np.linalg.norm(p[a] - p[b]) for a, b in self.pairs()])

    def pairs(self) -> list[tuple[int, int]]:
        """Index pairs ``(a, b)``, ``a < b``, into :attr:`ids`."""
        return [(a, b) for a in range(len(self.ids)) for b in range(a + 1, len(self.ids))]

    def summary(self) -> dict[str, object]:
        """``--json``: per-vehicle estimate in the reference's frame, distances, errors."""
        out: dict[str, object] = {
            "vehicles": self.ids,
            "reference": self.ids[0] if self.ids else None,
            "frames": self.frames,
            "duration_s": self.duration_s,
            "skipped": dict(sorted(self.counts.items())),
        }
        if self.state is None:
            return out
        p_all = np.vstack([np.zeros((1, 3)), self.state.p_ref])
        out["p_ref_m"] = {str(i): [float(x) for x in p_all[k]] for k, i in enumerate(self.ids)}
        pairs = self.pairs()
        d_est = np.array([np.linalg.norm(p_all[a] - p_all[b]) for a, b in pairs])
        out["distances_m"] = {
            f"{self.ids[a]}-{self.ids[b]}": float(d) for (a, b), d in zip(pairs, d_est, strict=True)
        }
        if all(i in self.truth for i in self.ids):
            p_true_ref, yaw_rel = self._truth_in_reference()
            d_true = np.array([np.linalg.norm(p_true_ref[a] - p_true_ref[b]) for a, b in pairs])
            out["truth_age_s"] = self.truth_age_s
            out["final_scale"] = float(np.sum(d_est * d_true) / np.sum(d_true**2))
            out["scale_error"] = float(np.max(np.abs(d_est / d_true - 1.0)))
            err = np.linalg.norm(p_all - p_true_ref, axis=1)
            rot_err = [
                float(
                    np.degrees(
                        np.arccos(np.clip((np.trace(rot_z(y).T @ r) - 1.0) / 2.0, -1.0, 1.0))
                    )
                )
                for y, r in zip(yaw_rel[1:], self.state.rot_ref_body, strict=True)
            ]
            out["position_error_m"] = {str(i): float(e) for i, e in zip(self.ids, err, strict=True)}
            out["rotation_error_deg"] = {
                str(i): e for i, e in zip(self.ids[1:], rot_err, strict=True)
            }
        return out

    def _truth_in_reference(self) -> tuple[FloatArray, FloatArray]:
        p = np.array([self.truth[i][0] for i in self.ids])
        yaw = np.array([self.truth[i][1] for i in self.ids])
        r0 = rot_z(yaw[0])
        return (p - p[0]) @ r0, yaw - yaw[0]


def _sample(t_s: float, state: Se3EkfState) -> EstimateSample:
    m = len(state.p_ref)
    var = np.diagonal(state.cov)[: 3 * m].reshape(m, 3).sum(axis=1)
    return EstimateSample(
        t_s,
        np.vstack([np.zeros((1, 3)), state.p_ref]),
        np.concatenate([[0.0], np.sqrt(np.maximum(var, 0.0))]),
    )


def _count(counts: dict[str, int], word: str) -> None:
    counts[word] = counts.get(word, 0) + 1


def replay_estimate(path: str | Path, cfg: ReplayConfig | None = None) -> ReplayResult:
    """Run the filter over a recording (module doc). Raises ``NotMcapError`` for a non-MCAP."""
    cfg = cfg if cfg is not None else ReplayConfig()
    counts: dict[str, int] = {}
    motions: list[MotionShare] = []
    frames: list[BearingShare] = []
    truth_log: dict[int, list[tuple[float, FloatArray, float]]] = {}
    for rec in read_recording(path).records:
        if rec.encoding != ZENOH_ENCODING:
            continue
        payloads, reasons = decode_payloads(rec.data)
        for reason in reasons:
            _count(counts, f"undecodable_{reason}")
        for payload in payloads:
            if isinstance(payload, MotionShare):
                motions.append(payload)
            elif isinstance(payload, BearingShare):
                frames.append(payload)
            elif isinstance(payload, Truth):
                truth_log.setdefault(payload.sender, []).append(
                    (payload.stamp_s, np.array(payload.p_ned, dtype=float), float(payload.yaw_rad))
                )
    ids = sorted({m.sender for m in motions})
    result = ReplayResult(ids=ids, state=None, counts=counts, truth_log=truth_log)
    if len(ids) < 2:
        _count(counts, "fewer_than_2_vehicles_with_odometry")
        return result
    # the whole recording is known: the team is fixed, and a sorted stream has no late samples
    loop = EkfLoop(replace(cfg, late_s=math.inf), fixed_ids=ids)
    stream = [(m.stamp_s, 0, m) for m in motions] + [(f.stamp_s, 1, f) for f in frames]
    stream.sort(key=lambda s: (s[0], s[1]))  # odometry first at equal stamps
    for _, _, sample in stream:
        if isinstance(sample, MotionShare):
            loop.add_motion(sample)
        elif loop.add_frame(sample) and loop.state is not None and loop.t_s is not None:
            last = result.history[-1].t_s if result.history else -math.inf
            if loop.t_s - last >= HISTORY_PERIOD_S:
                result.history.append(_sample(loop.t_s, loop.state))
    for word, k in loop.counts.items():
        counts[word] = counts.get(word, 0) + k
    result.state = loop.state
    result.frames = loop.updates
    if frames:
        result.duration_s = float(frames[-1].stamp_s - frames[0].stamp_s)
        t_end = loop.t_s if loop.t_s is not None else frames[-1].stamp_s
        for i, log in truth_log.items():  # the truth sample nearest the final estimate's time
            stamp, p, yaw = min(log, key=lambda s: abs(s[0] - t_end))
            result.truth[i] = (p, yaw)
            result.truth_age_s = max(result.truth_age_s, abs(stamp - t_end))
    return result

"""Paper 001's centralized EKF fed one sample at a time: the loop shared by
``bearingflock gcs estimate`` (live, over Zenoh) and ``--replay FILE.mcap`` (a recording).

Pure logic, no I/O: :class:`EkfLoop` takes the team's odometry (:class:`messages.peer.MotionShare`:
body velocity and yaw rate), camera frames (:class:`messages.peer.BearingShare`: body-frame
bearings) and, to cross-check, the daemons' own estimates (``p_hat_ned``, ``yaw_hat_rad`` of
:class:`messages.agent.AgentStatus` or :class:`messages.peer.LocalizationState`), all stamped in
the team's clock (``stamp_s``). The vehicles are ``R^3 x S^1`` multicopters (levelled bearings,
yaw rates): the ``SE(3)`` model of :mod:`onboard.estimation.se3_ekf` with ``w = (0, 0, yaw
rate)``; the first vehicle of :attr:`EkfLoop.ids` is the reference (paper 001 eq. 34-43, moving
reference: docs/equations.md, "Centralized EKF on SE(3)^N").

At each camera frame the filter predicts from the previous frame with each vehicle's latest
odometry (zero-order hold; odometry older than ``stale_s`` counts as ``stale_odometry`` and
enters as zero input with a large uncertainty) and updates with the frame's bearings.

Team membership (``fixed_ids=None``, live): the first vehicle heard with odometry and a camera
frame is the reference; another with odometry joins when a member has a bearing to it, placed
``prior_radius_m`` along that bearing (the filter does not know the scale), its yaw from its own
bearing back to that member when it has one (levelled bearings), with the prior's standard
deviations. One silent for more than ``silent_s`` (no odometry, no frame) is dropped from the
state (its block marginalized out; a dropped reference hands over to the next vehicle: the state
is re-expressed in that vehicle's frame, the covariance mapped through the change of frame); it
is re-added when it is heard again. Every join and drop is an :class:`Event` with a message.

Bad input is counted (:attr:`EkfLoop.counts`) and skipped, never raised: non-finite odometry,
bearings or estimates, samples older than the filter's time by more than ``late_s`` (stale),
bearings that are not unit vectors or name a vehicle not in the state.

Tilted vehicles (un-levelled bearings plus the autopilot's attitude): a caller with a vehicle's
raw sensors (the flight stack, a recording of camera bearings and ATTITUDE) feeds
:meth:`EkfLoop.add_attitude` (ATTITUDE's roll, pitch, yaw) or
:meth:`EkfLoop.add_attitude_quaternion` (ATTITUDE_QUATERNION), then
:meth:`EkfLoop.add_body_frame` (tilted body-frame or camera-frame bearings) and
:meth:`EkfLoop.add_body_motion` (tilted body-frame velocity, gyro ``(p, q, r)``). They are
levelled with the attitude interpolated at their stamps (:mod:`onboard.estimation.se3_inputs`:
``T beta``, ``T v``, the Euler yaw rate; why levelling and not the filter on tilted frames:
that module's doc and docs/equations.md) and enter as the levelled samples above, their noise
inflated by ``attitude_sigma_rad`` through the Jacobians. The daemons' messages do not carry
roll and pitch (:class:`messages.peer.BearingShare` has the yaw only): the daemons level their
bearings before sending them, so ``gcs estimate`` keeps taking their levelled samples. Bad
attitude is counted by name (``nonfinite_attitude``, ``non_unit_quaternion``,
``attitude_out_of_range``, ``not_a_rotation``, ``stale_attitude``) and skipped; a body sample
with no attitude within ``attitude_max_gap_s`` of its stamp counts ``no_attitude``.

Cross-check: each vehicle's EKF pose in the reference's frame beside the daemons' estimates
expressed in the same frame (``R_z(psi_ref)^T (p_j - p_ref)``, ``psi_j - psi_ref``; the daemons'
shared frame is arbitrary, only relative poses compare). The disagreement is the distance
between the two positions; it raises an alarm (a counted ``disagreement`` event) when it stays
above ``max_disagreement_m`` for ``alarm_hold_s`` once the EKF has settled on that vehicle (in
the filter for ``settle_s``, its largest position standard deviation below half the bound), and
an ``agreement`` event when it falls below 0.8 times the bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from messages.peer import BearingShare, MotionShare, TargetBearing
from onboard.estimation import se3_inputs
from onboard.estimation.se3_ekf import (
    Se3EkfState,
    initial_state,
    local_difference,
    predict,
    retract,
    scale_direction,
    update,
)
from onboard.estimation.se3_inputs import AttitudeBuffer, BadAttitude
from onboard.geometry import FloatArray, rot_z

DEFAULT_MAX_DISAGREEMENT_M = 1.5
"""Default alarm bound between the EKF's and the daemons' relative positions (m)."""


@dataclass(frozen=True)
class EkfLoopConfig:
    """Filter and bookkeeping settings (noise levels are 1-sigma)."""

    bearing_sigma_rad: float = math.radians(1.0)
    velocity_sigma_m_s: float = 0.1
    rate_sigma_rad_s: float = 0.02
    stale_s: float = 0.5
    """Odometry older than this at a frame enters as zero input with a large uncertainty."""
    stale_velocity_sigma_m_s: float = 2.0
    prior_radius_m: float = 3.0
    prior_sigma_p_m: float = 3.0
    prior_sigma_theta_rad: float = 1.0
    silent_s: float = 3.0
    """A vehicle heard from neither odometry nor frames for this long is dropped (live only)."""
    late_s: float = 1.0
    """A sample stamped this much before the filter's time is stale: counted and skipped."""
    max_disagreement_m: float = DEFAULT_MAX_DISAGREEMENT_M
    daemon_stale_s: float = 3.0
    settle_s: float = 10.0
    """No alarm about a vehicle in its first seconds in the filter: a bearing-only EKF started
    from an uninformed prior is overconfident until the motion has revealed the scale."""
    alarm_hold_s: float = 1.0
    """The disagreement must last this long to raise the alarm; it clears below 0.8 x bound."""
    attitude_sigma_rad: float = 0.0
    """Standard deviation of the autopilot's roll and pitch, each (tilted vehicles only)."""
    attitude_max_gap_s: float = 0.25
    """A body sample levels with the attitude interpolated at its stamp, or the nearest one
    within this; without one it is counted (``no_attitude``) and skipped."""
    """A daemon estimate older than this (vs. the filter's time) is not compared."""


@dataclass(frozen=True)
class Event:
    """Something the operator should read: ``kind`` is ``joined``, ``dropped``, ``re_added``,
    ``reference_changed``, ``disagreement`` or ``agreement``."""

    t_s: float
    kind: str
    vehicle: int
    message: str


def _finite(*xs: Any) -> bool:
    try:
        return bool(np.all(np.isfinite(np.asarray(xs, dtype=float))))
    except (TypeError, ValueError):
        return False


def yaw_of(rot: FloatArray) -> float:
    """Yaw (rad) of a rotation matrix, ``(3, 3) -> float`` (the levelled vehicles' heading)."""
    return float(math.atan2(rot[1, 0], rot[0, 0]))


def _wrap(a: float) -> float:
    return float((a + math.pi) % (2.0 * math.pi) - math.pi)


def _blocks(m: int, k: int) -> list[int]:
    """Error-state indices of state agent ``k`` of ``m``: ``dp_k`` then ``dtheta_k``."""
    return [3 * k, 3 * k + 1, 3 * k + 2, 3 * m + 3 * k, 3 * m + 3 * k + 1, 3 * m + 3 * k + 2]


def marginalize(state: Se3EkfState, k: int) -> Se3EkfState:
    """Remove state agent ``k`` (``0..M-1``): its pose and its rows/columns of the covariance
    (exact marginalization of a Gaussian). ``M -> M-1`` agents."""
    m = len(state.p_ref)
    drop = set(_blocks(m, k))
    keep = [c for c in range(6 * m) if c not in drop]
    idx = [c for c in range(m) if c != k]
    return Se3EkfState(
        state.p_ref[idx].copy(), state.rot_ref_body[idx].copy(), state.cov[np.ix_(keep, keep)]
    )


def augment(
    state: Se3EkfState, p_m: FloatArray, rot: FloatArray, sigma_p_m: float, sigma_theta_rad: float
) -> Se3EkfState:
    """Append one agent at prior ``(p_m (3,), rot (3, 3))``, independent of the others."""
    m = len(state.p_ref)
    p = np.vstack([state.p_ref, p_m[None]])
    r = np.concatenate([state.rot_ref_body, rot[None]])
    cov = np.zeros((6 * (m + 1), 6 * (m + 1)))
    old = [c for c in range(6 * (m + 1)) if c not in _blocks(m + 1, m)]
    cov[np.ix_(old, old)] = state.cov
    new = _blocks(m + 1, m)
    cov[new, new] = [sigma_p_m**2] * 3 + [sigma_theta_rad**2] * 3
    return Se3EkfState(p, r, cov)


def _rebased(p: FloatArray, rot: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Poses relative to state agent 0, the old reference ``(0, I)`` taking its place."""
    r0t = rot[0].T
    p_new = np.vstack([-(r0t @ p[0])[None], (p[1:] - p[0]) @ r0t.T])
    rot_new = np.concatenate([r0t[None], r0t @ rot[1:]])
    return p_new, rot_new


def rebase(state: Se3EkfState, eps: float = 1e-6) -> Se3EkfState:
    """Make state agent 0 the reference (``p_i' = R_0^T (p_i - p_0)``, ``R_i' = R_0^T R_i``; the
    old reference becomes state agent 0 at ``(-R_0^T p_0, R_0^T)``); the covariance maps through
    the change of frame's Jacobian on the manifold (central differences, ``(6M, 6M)``)."""
    m = len(state.p_ref)
    p_new, rot_new = _rebased(state.p_ref, state.rot_ref_body)
    jac = np.zeros((6 * m, 6 * m))
    for c in range(6 * m):
        dx = np.zeros(6 * m)
        dx[c] = eps
        pp, rp = _rebased(*retract(state.p_ref, state.rot_ref_body, dx))
        pm, rm = _rebased(*retract(state.p_ref, state.rot_ref_body, -dx))
        jac[:, c] = (
            local_difference(p_new, rot_new, pp, rp) - local_difference(p_new, rot_new, pm, rm)
        ) / (2 * eps)
    cov = jac @ state.cov @ jac.T
    return Se3EkfState(p_new, rot_new, 0.5 * (cov + cov.T))


@dataclass
class DaemonEstimate:
    """A daemon's own estimate in the team's shared (arbitrary) frame."""

    stamp_s: float
    p_hat_ned: FloatArray
    yaw_hat_rad: float


@dataclass
class EkfLoop:
    """The filter, its team and its counters (module doc). ``fixed_ids``: a known team (the
    replay: sorted ids, nobody joins or is dropped); ``None``: live membership."""

    cfg: EkfLoopConfig = field(default_factory=EkfLoopConfig)
    fixed_ids: list[int] | None = None
    ids: list[int] = field(default_factory=list)
    """Vehicles in the state, the reference first."""
    state: Se3EkfState | None = None
    updates: int = 0
    counts: dict[str, int] = field(default_factory=dict)
    events: list[Event] = field(default_factory=list)
    event_counts: dict[str, int] = field(default_factory=dict)
    t_s: float | None = None
    """The filter's time: the latest frame it processed."""
    first_frame_s: float | None = None
    latest: dict[int, MotionShare] = field(default_factory=dict)
    heard_s: dict[int, float] = field(default_factory=dict)
    daemons: dict[int, DaemonEstimate] = field(default_factory=dict)
    alarms: set[int] = field(default_factory=set)
    last_frame: dict[int, BearingShare] = field(default_factory=dict)
    joined_s: dict[int, float] = field(default_factory=dict)
    over_since_s: dict[int, float] = field(default_factory=dict)
    dropped: set[int] = field(default_factory=set)
    """Vehicles dropped as silent and not back yet."""
    attitudes: dict[int, AttitudeBuffer] = field(default_factory=dict)
    """Tilted vehicles' attitude histories."""
    motion_std: dict[int, tuple[float, float]] = field(default_factory=dict)
    """Input standard deviations (v m/s, w rad/s) of a vehicle whose latest odometry was
    levelled (:meth:`add_body_motion`); others use the configuration's."""
    max_events: int = 200

    def __post_init__(self) -> None:
        if self.fixed_ids is not None:
            self.ids = list(self.fixed_ids)
            if len(self.ids) >= 2:
                self.state = self._prior_state(len(self.ids))

    # --- bookkeeping -------------------------------------------------------------------------
    def count(self, word: str) -> None:
        self.counts[word] = self.counts.get(word, 0) + 1

    def _event(self, t_s: float, kind: str, vehicle: int, message: str) -> None:
        self.event_counts[kind] = self.event_counts.get(kind, 0) + 1
        self.events.append(Event(t_s, kind, vehicle, message))
        del self.events[: max(0, len(self.events) - self.max_events)]

    def _prior_state(self, n: int) -> Se3EkfState:
        angles = 2.0 * np.pi * np.arange(1, n) / n
        r = self.cfg.prior_radius_m
        p0 = r * np.stack([np.cos(angles), np.sin(angles), np.zeros(n - 1)], axis=1)
        return initial_state(
            p0,
            np.tile(np.eye(3), (n - 1, 1, 1)),
            self.cfg.prior_sigma_p_m,
            self.cfg.prior_sigma_theta_rad,
        )

    def _is_late(self, stamp_s: float) -> bool:
        return self.t_s is not None and stamp_s < self.t_s - self.cfg.late_s

    # --- membership (live) -------------------------------------------------------------------
    def _pose_of(self, i: int) -> tuple[FloatArray, FloatArray]:
        """Mean pose of member ``i`` in the reference's frame (the reference: ``(0, I)``)."""
        k = self.ids.index(i)
        if k == 0 or self.state is None:
            return np.zeros(3), np.eye(3)
        return self.state.p_ref[k - 1], self.state.rot_ref_body[k - 1]

    def _yaw_prior(self, i: int, j: int, u_ref: FloatArray, t_s: float) -> float:
        """Yaw of newcomer ``i`` in the reference's frame from its own recent bearing to member
        ``j``, ``u_ref`` the direction from ``i`` to ``j`` there (levelled bearings:
        ``R_z(psi_i) beta_ij = u``); ``0`` without one."""
        f = self.last_frame.get(i)
        if f is None or abs(f.stamp_s - t_s) > self.cfg.stale_s:
            return 0.0
        for target, b in ((e.target, e.beta_body) for e in f.bearings):
            if target == j and _finite(*b) and len(b) == 3 and math.hypot(b[0], b[1]) > 0.1:
                return _wrap(math.atan2(u_ref[1], u_ref[0]) - math.atan2(b[1], b[0]))
        return 0.0

    def _admit(self, frame: BearingShare) -> None:
        """Live membership: a vehicle with odometry enters the state when a member (or, for an
        empty team, the frame's sender itself, then the reference) has a bearing to it, at
        ``prior_radius_m`` along that bearing, its yaw from its own bearing back (module doc)."""
        s = frame.sender
        if s not in self.latest:
            return
        if not self.ids:
            self._event(frame.stamp_s, *self._joined_words(s, frame.stamp_s))
            self.ids.append(s)
        if s not in self.ids:
            return
        for target, b in ((e.target, e.beta_body) for e in frame.bearings):
            if target in self.ids or target not in self.latest or target == s:
                continue
            bv = np.asarray(b, dtype=float)
            if bv.shape != (3,) or not np.all(np.isfinite(bv)) or np.linalg.norm(bv) < 0.5:
                continue
            p_s, r_s = self._pose_of(s)
            u = r_s @ (bv / np.linalg.norm(bv))
            p = p_s + self.cfg.prior_radius_m * u
            rot = rot_z(self._yaw_prior(target, s, -u, frame.stamp_s))
            sig_p, sig_th = self.cfg.prior_sigma_p_m, self.cfg.prior_sigma_theta_rad
            if self.state is None:
                self.state = initial_state(p[None], rot[None], sig_p, sig_th)
                self.t_s = None  # a new filter: no prediction before its first frame
            else:
                self.state = augment(self.state, p, rot, sig_p, sig_th)
            self.ids.append(target)
            self._event(frame.stamp_s, *self._joined_words(target, frame.stamp_s))

    def _joined_words(self, i: int, t_s: float) -> tuple[str, int, str]:
        self.joined_s[i] = t_s
        if i in self.dropped:
            self.dropped.discard(i)
            return "re_added", i, f"vehicle {i} re-added: heard again"
        return "joined", i, f"vehicle {i} joined the filter"

    def _drop(self, i: int, t_s: float) -> None:
        k = self.ids.index(i)
        silent = t_s - self.heard_s.get(i, t_s)
        self._event(t_s, "dropped", i, f"vehicle {i} dropped: silent for {silent:.1f} s")
        self.alarms.discard(i)
        self.dropped.add(i)
        self.latest.pop(i, None)
        self.ids.pop(k)
        if self.state is None:
            return
        if len(self.ids) < 2:
            self.state = None
            return
        if k == 0:  # the reference: its successor takes over
            self.state = marginalize(rebase(self.state), 0)
            self._event(
                t_s, "reference_changed", self.ids[0], f"vehicle {self.ids[0]} is the reference"
            )
        else:
            self.state = marginalize(self.state, k - 1)

    def _drop_silent(self, t_s: float) -> None:
        if self.fixed_ids is not None:
            return
        for i in [i for i in self.ids if t_s - self.heard_s.get(i, t_s) > self.cfg.silent_s]:
            self._drop(i, t_s)

    # --- samples -----------------------------------------------------------------------------
    def add_motion(self, m: MotionShare) -> None:
        """One vehicle's odometry (heading-frame velocity, yaw rate)."""
        self._accept_motion(m, None)

    def _accept_motion(self, m: MotionShare, std: tuple[float, float] | None) -> None:
        if not _finite(m.stamp_s, m.yaw_rate_rad_s, *m.v_body) or len(m.v_body) != 3:
            self.count("nonfinite_odometry")
            return
        prev = self.latest.get(m.sender)
        if self._is_late(m.stamp_s) or (prev is not None and m.stamp_s < prev.stamp_s):
            self.count("stale_sample")
            return
        self.latest[m.sender] = m
        self.heard_s[m.sender] = max(self.heard_s.get(m.sender, m.stamp_s), m.stamp_s)
        if std is None:
            self.motion_std.pop(m.sender, None)
        else:
            self.motion_std[m.sender] = std

    # --- tilted vehicles: un-levelled samples plus the autopilot's attitude ------------------
    def _buffer(self, sender: int) -> AttitudeBuffer:
        if sender not in self.attitudes:
            self.attitudes[sender] = AttitudeBuffer(max_gap_s=self.cfg.attitude_max_gap_s)
        return self.attitudes[sender]

    def add_attitude(
        self, sender: int, stamp_s: float, roll_rad: float, pitch_rad: float, yaw_rad: float
    ) -> None:
        """The autopilot's attitude (MAVLink ATTITUDE, ZYX, rad) at ``stamp_s``."""
        try:
            self._buffer(sender).add(
                stamp_s, se3_inputs.rotation_from_euler(roll_rad, pitch_rad, yaw_rad)
            )
        except (BadAttitude, TypeError) as exc:
            self.count(getattr(exc, "word", "nonfinite_attitude"))

    def add_attitude_quaternion(self, sender: int, stamp_s: float, q_wxyz: Any) -> None:
        """The autopilot's attitude (MAVLink ATTITUDE_QUATERNION ``(w, x, y, z)``)."""
        try:
            self._buffer(sender).add(stamp_s, se3_inputs.rotation_from_quaternion(q_wxyz))
        except (BadAttitude, TypeError, ValueError) as exc:
            self.count(getattr(exc, "word", "nonfinite_attitude"))

    def _attitude_at(self, sender: int, stamp_s: float) -> tuple[float, float, float] | None:
        """``(roll, pitch, yaw)`` of ``sender`` at ``stamp_s``, or ``None`` (counted)."""
        buf = self.attitudes.get(sender)
        rot = None if buf is None or not _finite(stamp_s) else buf.at(stamp_s)
        if rot is None:
            self.count("no_attitude")
            return None
        return se3_inputs.euler_from_rotation(rot)

    def add_body_frame(
        self,
        sender: int,
        stamp_s: float,
        bearings: Any,
        rot_body_cam: Any = None,
    ) -> bool:
        """One camera frame of a tilted vehicle: ``bearings`` ``[(target, beta (3,)), ...]`` in
        its tilted body frame (or, with ``rot_body_cam``, its camera frame), levelled with the
        attitude at ``stamp_s`` and processed as :meth:`add_frame`; ``True`` if it updated."""
        att = self._attitude_at(sender, stamp_s)
        if att is None:
            return False
        roll, pitch, yaw = att
        entries, good = [], []
        for target, b in bearings:
            bv = np.asarray(b, dtype=float)
            if bv.shape != (3,) or not np.all(np.isfinite(bv)):
                self.count("bad_bearing")
                continue
            if rot_body_cam is not None:
                bv = np.asarray(rot_body_cam, dtype=float) @ bv
            good.append(bv)
            bl = se3_inputs.level(bv, roll, pitch)
            entries.append(TargetBearing(int(target), (float(bl[0]), float(bl[1]), float(bl[2]))))
        sigma = None
        if good and self.cfg.attitude_sigma_rad > 0.0:
            sigma = se3_inputs.levelled_bearing_sigma_rad(
                np.array(good), roll, pitch, self.cfg.bearing_sigma_rad, self.cfg.attitude_sigma_rad
            )
        frame = BearingShare(sender=sender, stamp_s=stamp_s, yaw_rad=yaw, bearings=entries)
        return self.add_frame(frame, sigma_rad=sigma)

    def add_body_motion(
        self, sender: int, stamp_s: float, v_body_m_s: Any, w_body_rad_s: Any
    ) -> None:
        """One tilted vehicle's odometry: velocity in its tilted body frame (m/s) and gyro
        ``(p, q, r)`` (rad/s), levelled with the attitude at ``stamp_s`` (module doc)."""
        try:
            v = np.asarray(v_body_m_s, dtype=float)
            w = np.asarray(w_body_rad_s, dtype=float)
        except (TypeError, ValueError):
            v = w = np.full(1, np.nan)
        if v.shape != (3,) or w.shape != (3,) or not _finite(stamp_s, *v, *w):
            self.count("nonfinite_odometry")
            return
        att = self._attitude_at(sender, stamp_s)
        if att is None:
            return
        roll, pitch, yaw = att
        v_h, rate = se3_inputs.heading_motion(v, w, roll, pitch)
        std = se3_inputs.heading_motion_sigmas(
            v,
            w,
            roll,
            pitch,
            self.cfg.velocity_sigma_m_s,
            self.cfg.rate_sigma_rad_s,
            self.cfg.attitude_sigma_rad,
        )
        m = MotionShare(
            sender=sender,
            stamp_s=stamp_s,
            v_body=(float(v_h[0]), float(v_h[1]), float(v_h[2])),
            yaw_rate_rad_s=rate,
            yaw_rad=yaw,
        )
        self._accept_motion(m, std)

    def add_daemon_estimate(
        self, sender: int, stamp_s: float, p_hat_ned: Any, yaw_hat_rad: float
    ) -> None:
        """A daemon's own pose estimate (status or ``peer.localization``)."""
        if not _finite(stamp_s, yaw_hat_rad, *p_hat_ned) or len(p_hat_ned) != 3:
            self.count("nonfinite_daemon_estimate")
            return
        prev = self.daemons.get(sender)
        if prev is not None and stamp_s < prev.stamp_s:
            self.count("stale_sample")
            return
        self.daemons[sender] = DaemonEstimate(
            float(stamp_s), np.asarray(p_hat_ned, dtype=float), float(yaw_hat_rad)
        )

    def add_frame(self, frame: BearingShare, sigma_rad: float | None = None) -> bool:
        """One camera frame (levelled bearings): predict to its time and update with angular
        noise ``sigma_rad`` (default: the configuration's); ``True`` if the filter updated."""
        t = frame.stamp_s
        if not _finite(t):
            self.count("nonfinite_stamp")
            return False
        if self._is_late(t):
            self.count("stale_sample")
            return False
        if frame.sender in self.latest:
            self.heard_s[frame.sender] = max(self.heard_s.get(frame.sender, t), t)
        self._drop_silent(t)
        if self.fixed_ids is None:
            self.last_frame[frame.sender] = frame
            self._admit(frame)
        if frame.sender not in self.ids:  # live: odometry heard, no member's bearing to it yet
            self.count(
                "bearings_from_vehicle_not_yet_in_filter"
                if frame.sender in self.latest
                else "bearings_from_vehicle_without_odometry"
            )
            return False
        if self.state is None:
            self.count("fewer_than_2_vehicles_with_odometry")
            return False
        index = {i: k for k, i in enumerate(self.ids)}
        if self.first_frame_s is None:
            self.first_frame_s = t
        if self.t_s is not None and t > self.t_s:
            self._predict(index, t)
        self.t_s = t if self.t_s is None else max(self.t_s, t)
        edges, beta = [], []
        for target, b in ((e.target, e.beta_body) for e in frame.bearings):
            if target not in index or target == frame.sender:
                self.count("bearing_to_unknown_vehicle")
                continue
            bv = np.asarray(b, dtype=float)
            if (
                bv.shape != (3,)
                or not np.all(np.isfinite(bv))
                or abs(np.linalg.norm(bv) - 1) > 1e-3
            ):
                self.count("bad_bearing")
                continue
            edges.append((index[frame.sender], index[target]))
            beta.append(bv)
        if not edges:
            return False
        sigma = self.cfg.bearing_sigma_rad if sigma_rad is None else sigma_rad
        self.state, _ = update(self.state, np.array(edges), np.array(beta), sigma)
        self.updates += 1
        self._check_disagreement()
        return True

    def _predict(self, index: dict[int, int], t: float) -> None:
        assert self.state is not None and self.t_s is not None
        n = len(index)
        v = np.zeros((n, 3))
        w = np.zeros((n, 3))
        std = np.zeros((n, 2))
        for i, k in index.items():
            m = self.latest.get(i)
            if m is None or t - m.stamp_s > self.cfg.stale_s:
                self.count("stale_odometry")
                std[k] = (self.cfg.stale_velocity_sigma_m_s, self.cfg.rate_sigma_rad_s * 10.0)
                continue
            v[k] = m.v_body
            w[k, 2] = m.yaw_rate_rad_s
            std[k] = self.motion_std.get(
                i, (self.cfg.velocity_sigma_m_s, self.cfg.rate_sigma_rad_s)
            )
        self.state = predict(self.state, v, w, t - self.t_s, std)

    # --- cross-check -------------------------------------------------------------------------
    def daemon_in_reference(self) -> dict[int, tuple[FloatArray, float]]:
        """The daemons' fresh estimates relative to the reference's: id -> (position (3,) m,
        yaw rad) in the reference's frame; empty without a fresh reference estimate."""
        if not self.ids or self.t_s is None:
            return {}
        ref = self.daemons.get(self.ids[0])
        fresh = self.cfg.daemon_stale_s
        if ref is None or self.t_s - ref.stamp_s > fresh:
            return {}
        r0t = rot_z(ref.yaw_hat_rad).T
        out = {}
        for i in self.ids:
            d = self.daemons.get(i)
            if d is not None and self.t_s - d.stamp_s <= fresh:
                out[i] = (
                    r0t @ (d.p_hat_ned - ref.p_hat_ned),
                    _wrap(d.yaw_hat_rad - ref.yaw_hat_rad),
                )
        return out

    def poses(self) -> dict[int, tuple[FloatArray, float, float]]:
        """The EKF's poses in the reference's frame: id -> (position (3,) m, yaw rad, largest
        position standard deviation m); the reference is ``(0, 0, 0)``."""
        if self.state is None:
            return {}
        s = self.state
        m = len(s.p_ref)
        out = {self.ids[0]: (np.zeros(3), 0.0, 0.0)}
        for k, i in enumerate(self.ids[1:]):
            sd = float(np.sqrt(np.max(np.diag(s.cov)[3 * k : 3 * k + 3])))
            out[i] = (s.p_ref[k].copy(), yaw_of(s.rot_ref_body[k]), sd)
        assert len(out) == m + 1
        return out

    def disagreements(self) -> dict[int, float]:
        """id -> distance (m) between the EKF's and the daemons' positions in the reference's
        frame, for every non-reference vehicle both know."""
        ekf, dmn = self.poses(), self.daemon_in_reference()
        return {
            i: float(np.linalg.norm(ekf[i][0] - dmn[i][0]))
            for i in self.ids[1:]
            if i in ekf and i in dmn
        }

    def _check_disagreement(self) -> None:
        bound = self.cfg.max_disagreement_m
        ekf = self.poses()
        t = self.t_s
        assert t is not None
        for i, d in self.disagreements().items():
            settled = t - self.joined_s.get(i, -math.inf) >= self.cfg.settle_s
            if d <= bound or not settled or ekf[i][2] >= 0.5 * bound:
                self.over_since_s.pop(i, None)
            else:
                self.over_since_s.setdefault(i, t)
            held = t - self.over_since_s.get(i, math.inf) >= self.cfg.alarm_hold_s
            if held and i not in self.alarms:
                self.alarms.add(i)
                self._event(
                    t,
                    "disagreement",
                    i,
                    f"ALARM vehicle {i}: EKF and daemons disagree by {d:.2f} m > {bound:.2f} m",
                )
            elif d < 0.8 * bound and i in self.alarms:
                self.alarms.discard(i)
                self._event(t, "agreement", i, f"vehicle {i}: agrees again ({d:.2f} m)")

    def scale(self) -> dict[str, float | None]:
        """The formation's size as the EKF sees it: ``scale_m`` (RMS distance between vehicles),
        ``scale_rel_sigma`` (relative standard deviation along the scale direction, paper 001
        sec. III) and ``daemon_scale_ratio`` (the daemons' RMS distance over the EKF's)."""
        if self.state is None:
            return {"scale_m": None, "scale_rel_sigma": None, "daemon_scale_ratio": None}
        p = np.vstack([np.zeros((1, 3)), self.state.p_ref])
        n = len(p)
        pairs = [(a, b) for a in range(n) for b in range(a + 1, n)]
        rms = float(np.sqrt(np.mean([np.sum((p[a] - p[b]) ** 2) for a, b in pairs])))
        sd = scale_direction(self.state.p_ref)
        rel = float(np.sqrt(max(0.0, sd @ self.state.cov @ sd)) / np.linalg.norm(self.state.p_ref))
        dmn = self.daemon_in_reference()
        ratio = None
        if all(i in dmn for i in self.ids) and rms > 0:
            q = np.array([dmn[i][0] for i in self.ids])
            ratio = float(np.sqrt(np.mean([np.sum((q[a] - q[b]) ** 2) for a, b in pairs])) / rms)
        return {"scale_m": rms, "scale_rel_sigma": rel, "daemon_scale_ratio": ratio}

    def summary(self) -> dict[str, Any]:
        """JSON-able state: vehicles, counters, events, scale, per-vehicle poses, alarms."""
        ekf, dmn, dis = self.poses(), self.daemon_in_reference(), self.disagreements()
        vehicles = {}
        for i in self.ids:
            row: dict[str, Any] = {}
            if i in ekf:
                p, yaw, sd = ekf[i]
                row |= {"p_ref_m": [float(x) for x in p], "yaw_ref_rad": yaw, "sigma_p_m": sd}
            if i in dmn:
                row |= {
                    "daemon_p_ref_m": [float(x) for x in dmn[i][0]],
                    "daemon_yaw_ref_rad": dmn[i][1],
                }
            if i in dis:
                row["disagreement_m"] = dis[i]
            row["alarm"] = i in self.alarms
            vehicles[str(i)] = row
        return {
            "vehicles": list(self.ids),
            "reference": self.ids[0] if self.ids else None,
            "updates": self.updates,
            "t_s": self.t_s,
            "max_disagreement_m": self.cfg.max_disagreement_m,
            **self.scale(),
            "poses": vehicles,
            "alarms": sorted(self.alarms),
            "skipped": dict(sorted(self.counts.items())),
            "event_counts": dict(sorted(self.event_counts.items())),
            "events": [
                {"t_s": e.t_s, "kind": e.kind, "vehicle": e.vehicle, "message": e.message}
                for e in self.events
            ],
        }

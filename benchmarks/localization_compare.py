"""One table for every localization method on the same work (issue 26).

Methods (docs/papers.md): paper 000's ``R^3 x S^1`` localization filter with SfM scale on every
reciprocal edge (``onboard/estimation/localization.py`` + ``sfm_observer.py``), paper 003's
angle-based estimator with one SfM distance (``onboard/estimation/angle_localization.py``),
paper 002's distributed gradient localization with that SfM distance as its range
(``onboard/distributed/localization.py``) and paper 001's centralized EKF
(``onboard/estimation/se3_ekf.py``, yaw-only rotations as the daemons have them).

The work, identical for every method of a cell (one seed draws it): ``N`` level multicopters
with smooth exciting motion (each axis ``c + a sin(w t + phi)``, yaw ``psi + b sin(...)``), every
agent seeing every other; camera frames (body bearings, angular noise ``noise_deg`` per
tangent axis) and messages at 10 Hz, odometry (body velocity 0.05 m/s, yaw rate 0.01 rad/s
noise) at 50 Hz and shared at 50 Hz (the SfM observers need the neighbours'); each message (sender, receiver, frame) lost with probability ``loss`` (the
ground station is one more receiver; odometry to it is never lost, as the daemons send it
integrated). Every method starts from the same prior: the true formation scaled by 1.3 about
its centroid plus 0.3 m per axis, yaws 10 degrees off.

Columns: position error after the best rigid alignment (Kabsch, no scale: a scale error shows
in it), scale error (RMS distance to the centroid, estimate over truth, minus 1), time from
which the scale error stays under 2%, CPU per agent per 50 Hz step (process time of the whole
method divided by ``N`` and the steps; the EKF runs at the ground station), and payload bytes
each agent sends per second (8 bytes per value, 2 per id, no headers; one broadcast counted
once). Medians over seeds. Paper 002 assumes known rotations: it is given each yaw as the
true initial yaw plus the integrated measured yaw rate.

    python benchmarks/localization_compare.py [--seeds 10] [--n 3 6 10] [--noise-deg 0 1 2]
        [--loss 0 0.1] [--duration-s 30] [--json FILE] [--markdown]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from onboard.distributed.localization import localization_gradients, localization_steps
from onboard.estimation import se3_ekf
from onboard.estimation.angle_localization import (
    AngleLocalizer,
    distance_gradient,
    local_angle_gradient,
    local_vertical_gradient,
)
from onboard.estimation.localization import LocalizationFilter
from onboard.estimation.sfm_observer import SfmEdge
from onboard.geometry import FloatArray, rot_z

DT_S = 0.02
FRAME_EVERY = 5  # 10 Hz frames and messages
V_STD_M_S = 0.05
W_STD_RAD_S = 0.01
PRIOR_SCALE = 1.3
PRIOR_P_STD_M = 0.3
PRIOR_YAW_STD_RAD = math.radians(10.0)
SCALE_TOL = 0.02
FLOAT_B = 8
ID_B = 2
P002_ROUNDS = 5


@dataclass(frozen=True)
class Work:
    """Truth, measurements and prior shared by every method of one cell."""

    p_ned: FloatArray  # (T, N, 3) truth at every step
    yaw_rad: FloatArray  # (T, N)
    v_meas: FloatArray  # (T, N, 3) body velocity
    w_meas: FloatArray  # (T, N) yaw rate
    beta: FloatArray  # (F, N, N, 3) body bearing i -> j at frame f (diagonal unused)
    delivered: FloatArray  # (F, N, N + 1) bool: sender -> receiver (N: the ground station)
    p0_ned: FloatArray  # (N, 3) prior
    yaw0_rad: FloatArray  # (N,)
    noise_rad: float

    @property
    def n(self) -> int:
        return self.p_ned.shape[1]


def make_work(n: int, seed: int, noise_deg: float, loss: float, duration_s: float) -> Work:
    """Seeded trajectories, measurements and prior (module doc)."""
    rng = np.random.default_rng(seed)
    side = 4.0 * math.sqrt(n)
    centres: list[FloatArray] = []
    misses = 0
    while len(centres) < n:
        c = np.array([rng.uniform(0, side), rng.uniform(0, side), -rng.uniform(2.0, 5.0)])
        if all(np.linalg.norm(c - d) > 4.5 for d in centres):
            centres.append(c)
        elif (misses := misses + 1) > 1000:  # the first centres left no room: start over
            centres, misses = [], 0
    c = np.array(centres)
    amp = rng.uniform(0.5, 1.0, (n, 3)) * np.array([1.0, 1.0, 0.3])
    om = rng.uniform(0.4, 1.2, (n, 3))
    ph = rng.uniform(0, 2 * np.pi, (n, 3))
    yaw_c, yaw_a, yaw_w = (
        rng.uniform(-np.pi, np.pi, n),
        rng.uniform(0.2, 0.6, n),
        rng.uniform(0.2, 0.6, n),
    )
    steps = round(duration_s / DT_S) + 1
    t = np.arange(steps)[:, None, None] * DT_S
    p = c + amp * np.sin(om * t + ph)
    pdot = amp * om * np.cos(om * t + ph)
    tt = t[:, :, 0]
    yaw = yaw_c + yaw_a * np.sin(yaw_w * tt)
    yaw_rate = yaw_a * yaw_w * np.cos(yaw_w * tt)
    rz = rot_z(yaw)  # (T, N, 3, 3)
    v_body = np.einsum("tnki,tnk->tni", rz, pdot)
    v_meas = v_body + rng.normal(0.0, V_STD_M_S, v_body.shape)
    w_meas = yaw_rate + rng.normal(0.0, W_STD_RAD_S, yaw_rate.shape)
    fr = np.arange(0, steps, FRAME_EVERY)
    pf, rf = p[fr], rz[fr]
    r = pf[:, None, :, :] - pf[:, :, None, :]  # (F, i, j, 3) p_j - p_i
    d = np.linalg.norm(r, axis=-1, keepdims=True)
    d[d == 0.0] = 1.0
    beta = np.einsum("fika,fijk->fija", rf, r / d)  # R_i^T (p_j - p_i) / d_ij
    noise = math.radians(noise_deg)
    if noise > 0.0:  # isotropic, then back on the sphere: ``noise`` rad per tangent axis
        beta = beta + rng.normal(0.0, noise, beta.shape)
        beta /= np.linalg.norm(beta, axis=-1, keepdims=True)
    delivered = rng.random((len(fr), n, n + 1)) >= loss
    cen = p[0].mean(axis=0)
    p0 = cen + PRIOR_SCALE * (p[0] - cen) + rng.normal(0.0, PRIOR_P_STD_M, (n, 3))
    yaw0 = yaw[0] + rng.normal(0.0, PRIOR_YAW_STD_RAD, n)
    return Work(p, yaw, v_meas, w_meas, beta, delivered, p0, yaw0, noise)


# ---------------------------------------------------------------------------------------------
# Shared pieces
# ---------------------------------------------------------------------------------------------


def _u_ij(yaw_i: float, yaw_j: float, v_i: FloatArray, v_j: FloatArray) -> tuple[float, ...]:
    """Relative velocity in ``i``'s body frame, ``iR_j u_j - u_i`` (paper 000 eq. 7)."""
    d = yaw_j - yaw_i
    c, s = math.cos(d), math.sin(d)
    return (c * v_j[0] - s * v_j[1] - v_i[0], s * v_j[0] + c * v_j[1] - v_i[1], v_j[2] - v_i[2])


def _sfm_edge(d0_m: float) -> SfmEdge:
    return SfmEdge(chi_hat=1.0 / d0_m)


def _beta_t(b: FloatArray) -> tuple[float, float, float]:
    return (float(b[0]), float(b[1]), float(b[2]))


def _msg_bytes(floats: int, ids: int = 0) -> int:
    return floats * FLOAT_B + ids * ID_B


ODOMETRY_BPS = _msg_bytes(4) / DT_S
"""Odometry shares (body velocity, yaw rate) at 50 Hz: the SfM observers need the neighbour's."""


def _odometry_view(w: Work, k: int, v_view: FloatArray) -> FloatArray:
    """``v_view[r, s]``: ``r``'s copy of ``s``'s body velocity, refreshed every step unless the
    step's frame message from ``s`` to ``r`` was lost."""
    mask = w.delivered[k // FRAME_EVERY, :, : w.n].T
    return np.where(mask[:, :, None], w.v_meas[k][None], v_view)


Method = Callable[[Work], tuple[FloatArray, float]]
"""``work -> (estimated positions (F, N, 3) at the frame times, bytes per second per agent)``."""


# ---------------------------------------------------------------------------------------------
# Paper 000: R^3 x S^1 localization filter with SfM distances on every reciprocal edge
# ---------------------------------------------------------------------------------------------


def run_paper000(w: Work) -> tuple[FloatArray, float]:
    """Each agent runs eq. 6 with its neighbours' last received shares; agent ``i < j`` runs the
    SfM observer of edge ``(i, j)`` and shares ``dhat_ij``. Shares (10 Hz): estimate, bearings,
    owned distances; odometry at 50 Hz."""
    n = w.n
    filt = [LocalizationFilter(_beta_t(w.p0_ned[i]), float(w.yaw0_rad[i])) for i in range(n)]
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    sfm = {e: _sfm_edge(float(np.linalg.norm(w.p0_ned[e[1]] - w.p0_ned[e[0]]))) for e in pairs}
    view: list[list[tuple | None]] = [[None] * n for _ in range(n)]
    v_view = np.zeros((n, n, 3))
    est = np.zeros((len(w.beta), n, 3))
    for k in range(len(w.v_meas)):
        t = k * DT_S
        v, wr = w.v_meas[k], w.w_meas[k]
        v_view = _odometry_view(w, k, v_view)
        if k % FRAME_EVERY == 0:
            f = k // FRAME_EVERY
            est[f] = [x.p_hat_ned for x in filt]
            dh = {e: 1.0 / s.chi_hat for e, s in sfm.items() if s.chi_hat > 0.0}
            for s_ in range(n):
                snap = (filt[s_].p_hat_ned, filt[s_].yaw_hat_rad, None, w.beta[f, s_], dh)
                for r in range(n):
                    if r != s_ and w.delivered[f, s_, r]:
                        view[r][s_] = snap
            for (i, j), obs in sfm.items():
                vj = view[i][j]
                if vj is not None:
                    u = _u_ij(filt[i].yaw_hat_rad, vj[1], v[i], v_view[i, j])
                    obs.new_bearing(_beta_t(w.beta[f, i, j]), t, t, u, float(wr[i]))
            beta_own = w.beta[f]
        for (i, j), obs in sfm.items():
            vj = view[i][j]
            if vj is not None:
                obs.step(
                    t, DT_S, _u_ij(filt[i].yaw_hat_rad, vj[1], v[i], v_view[i, j]), float(wr[i])
                )
        for i in range(n):
            out_e, in_e, dist = [], [], []
            for j in range(n):
                vj = view[i][j]
                if j == i or vj is None:
                    continue
                out_e.append((vj[0], _beta_t(beta_own[i, j])))
                in_e.append((vj[0], vj[1], _beta_t(vj[3][i])))
                e = (min(i, j), max(i, j))
                d = 1.0 / sfm[e].chi_hat if i < j else vj[4].get(e)
                if d is not None and math.isfinite(d) and d > 0.0:
                    dist.append((vj[0], d))
            filt[i].step(DT_S, _beta_t(v[i]), float(wr[i]), out_e, in_e, dist)
    owned = (n - 1) / 2.0  # distances shared per agent on average
    share = _msg_bytes(3 + 1 + 3 * (n - 1) + owned, (n - 1) + owned)
    return est, share / (FRAME_EVERY * DT_S) + ODOMETRY_BPS


# ---------------------------------------------------------------------------------------------
# Paper 003: angle-based localization with one SfM distance
# ---------------------------------------------------------------------------------------------


def run_paper003(w: Work) -> tuple[FloatArray, float]:
    """Eq. 10-11 with the gravity term; agent ``i`` evaluates its angles with its last received
    neighbour estimates and sends the neighbours' gradient blocks every step (lost with the
    frame's message); agent 0 runs the SfM observer of edge ``(0, 1)`` for the distance term.
    Yaw: odometry from 0 plus the offset read from bearings (``AngleLocalizer``)."""
    n = w.n
    loc = [AngleLocalizer(w.p0_ned[i].copy()) for i in range(n)]
    yaw_odo = np.zeros(n)
    obs = _sfm_edge(float(np.linalg.norm(w.p0_ned[1] - w.p0_ned[0])))
    view = np.tile(w.p0_ned[None], (n, 1, 1))  # view[r, s]: r's copy of s's estimate
    yaw_view = np.zeros((n, n))
    v_view = np.zeros((n, n, 3))
    est = np.zeros((len(w.beta), n, 3))
    others = [np.array([j for j in range(n) if j != i]) for i in range(n)]
    for k in range(len(w.v_meas)):
        t = k * DT_S
        v, wr = w.v_meas[k], w.w_meas[k]
        v_view = _odometry_view(w, k, v_view)
        if k % FRAME_EVERY == 0:
            f = k // FRAME_EVERY
            est[f] = [x.p_hat_ned for x in loc]
            mask = w.delivered[f, :, :n].T  # mask[r, s]
            p_now = np.array([x.p_hat_ned for x in loc])
            yaw_now = np.array([x.yaw_hat(yaw_odo[i]) for i, x in enumerate(loc)])
            view = np.where(mask[:, :, None], p_now[None], view)
            yaw_view = np.where(mask, yaw_now[None], yaw_view)
            for i in range(n):
                loc[i].update_yaw(yaw_odo[i], w.beta[f, i, others[i]], view[i, others[i]])
            obs.new_bearing(
                _beta_t(w.beta[f, 0, 1]), t, t,
                _u_ij(loc[0].yaw_hat(yaw_odo[0]), yaw_view[0, 1], v[0], v_view[0, 1]), float(wr[0]),
            )  # fmt: skip
            beta_f, mask_f = w.beta[f], mask
        obs.step(
            t,
            DT_S,
            _u_ij(loc[0].yaw_hat(yaw_odo[0]), yaw_view[0, 1], v[0], v_view[0, 1]),
            float(wr[0]),
        )
        grad = np.zeros((n, 3))
        for i in range(n):
            o = others[i]
            p_i = loc[i].p_hat_ned
            _, g = local_angle_gradient(p_i, view[i, o], beta_f[i, o])
            _, gz = local_vertical_gradient(p_i, view[i, o], beta_f[i, o])
            g = g + gz
            if i == 0 and obs.chi_hat > 0.0:
                _, gd = distance_gradient(p_i, view[0, 1], 1.0 / obs.chi_hat)
                g[0] += gd
                g[1] -= gd  # row of agent 1 (others[0][0] == 1)
            grad[i] += g[0]
            keep = mask_f[o, i]  # the block reaches j with i's message
            grad[o[keep]] += g[1:][keep]
        for i in range(n):
            loc[i].step(DT_S, v[i], yaw_odo[i], grad[i])
        yaw_odo += DT_S * wr
    share = _msg_bytes(3 + 1, 0) / (FRAME_EVERY * DT_S) + _msg_bytes(3 * (n - 1), n - 1) / DT_S
    return est, share + ODOMETRY_BPS


# ---------------------------------------------------------------------------------------------
# Paper 002: distributed gradient localization (known rotations) with one SfM range
# ---------------------------------------------------------------------------------------------


def run_paper002(w: Work) -> tuple[FloatArray, float]:
    """Eq. 16 + 22 (range on edge ``(0, 1)`` from agent 0's SfM observer), ``P002_ROUNDS``
    Jacobi-scaled gradient rounds per frame on the world bearings ``u_ij = R_z(yaw_i) beta_ij``,
    estimates carried between frames by odometry. Each edge's term is evaluated at its measurer
    (its own ``T``, its copy of the other's) and at its target (own ``T``, copies of the measurer's
    ``T`` and ``lambda``): a lost message leaves the old copies."""
    n = w.n
    edges = np.array([(i, j) for i in range(n) for j in range(n) if i != j])
    ne = len(edges)
    a_, b_ = edges[:, 0], edges[:, 1]
    range_edge = int(np.flatnonzero((a_ == 0) & (b_ == 1))[0])
    h_t, h_l = localization_steps(edges, n)
    tr = w.p0_ned.copy()
    lam = np.linalg.norm(tr[b_] - tr[a_], axis=1)
    yaw = w.yaw_rad[0].copy()  # paper 002's known rotations (module doc)
    view = np.tile(tr[None], (n, 1, 1))
    lam_view = np.tile(lam[None], (n, 1))
    v_view = np.zeros((n, n, 3))
    obs = _sfm_edge(float(lam[range_edge]))
    idx = np.arange(ne)
    est = np.zeros((len(w.beta), n, 3))
    for k in range(len(w.v_meas)):
        t = k * DT_S
        v, wr = w.v_meas[k], w.w_meas[k]
        v_view = _odometry_view(w, k, v_view)
        if k % FRAME_EVERY == 0:
            f = k // FRAME_EVERY
            est[f] = tr
            mask = w.delivered[f, :, :n].T
            u = np.einsum("eab,eb->ea", rot_z(yaw[a_]), w.beta[f, a_, b_])
            obs.new_bearing(
                _beta_t(w.beta[f, 0, 1]),
                t,
                t,
                _u_ij(yaw[0], yaw[1], v[0], v_view[0, 1]),
                float(wr[0]),
            )
            rg = np.full(ne, np.nan)
            if obs.chi_hat > 0.0:
                rg[range_edge] = 1.0 / obs.chi_hat
            for _ in range(P002_ROUNDS):
                view = np.where(mask[:, :, None], tr[None], view)
                lam_view = np.where(
                    mask[b_, a_][None, :] & (np.arange(n)[:, None] == b_[None]), lam[None], lam_view
                )
                # measurer's evaluation: T_a own, copy of T_b; target's: copy of T_a, T_b own
                t_m = np.vstack([tr[a_], view[a_, b_]])
                g_m = localization_gradients(t_m, lam, np.c_[idx, idx + ne], u, rg)
                t_t = np.vstack([view[b_, a_], tr[b_]])
                g_t = localization_gradients(t_t, lam_view[b_, idx], np.c_[idx, idx + ne], u, rg)
                g_node = np.zeros((n, 3))
                np.add.at(g_node, a_, g_m.g_src)
                np.add.at(g_node, b_, g_t.g_dst)
                tr = tr - h_t[:, None] * g_node
                lam = lam - h_l * g_m.g_edge
        obs.step(t, DT_S, _u_ij(yaw[0], yaw[1], v[0], v_view[0, 1]), float(wr[0]))
        tr = tr + DT_S * np.einsum("nab,nb->na", rot_z(yaw), v)
        yaw = yaw + DT_S * wr
    per_round = _msg_bytes(3 + (n - 1), n - 1)
    share = _msg_bytes(3 * (n - 1), 0) + P002_ROUNDS * per_round
    return est, share / (FRAME_EVERY * DT_S) + ODOMETRY_BPS


# ---------------------------------------------------------------------------------------------
# Paper 001: centralized EKF at the ground station
# ---------------------------------------------------------------------------------------------


def run_paper001(w: Work) -> tuple[FloatArray, float]:
    """The EKF of ``se3_ekf`` on ``R^3 x S^1`` (yaw rates as ``w = (0, 0, r)``, levelled body
    bearings), agent 0 the moving reference; the ground station predicts at 50 Hz and updates
    with the bearings of the frames it received."""
    n = w.n
    p_rel, rot_rel = se3_ekf.relative_poses(w.p0_ned, rot_z(w.yaw0_rad))
    spread = float(np.median(np.linalg.norm(p_rel, axis=1)))
    sig_p = math.hypot((PRIOR_SCALE - 1.0) / PRIOR_SCALE * spread, 2.0 * PRIOR_P_STD_M)
    st = se3_ekf.initial_state(p_rel, rot_rel, sig_p, 2.0 * PRIOR_YAW_STD_RAD)
    std = np.tile([V_STD_M_S, W_STD_RAD_S], (n, 1))
    sigma = max(w.noise_rad, math.radians(0.1))
    edges_all = np.array([(i, j) for i in range(n) for j in range(n) if i != j])
    est = np.zeros((len(w.beta), n, 3))
    wb = np.zeros((n, 3))
    for k in range(len(w.v_meas)):
        if k % FRAME_EVERY == 0:
            f = k // FRAME_EVERY
            got = w.delivered[f, edges_all[:, 0], n]
            if got.any():
                e = edges_all[got]
                st, _ = se3_ekf.update(st, e, w.beta[f, e[:, 0], e[:, 1]], sigma)
            est[f] = se3_ekf.full_poses(st.p_ref, st.rot_ref_body)[0]
        wb[:, 2] = w.w_meas[k]
        st = se3_ekf.predict(st, w.v_meas[k], wb, DT_S, std)
    return est, ODOMETRY_BPS + _msg_bytes(3 * (n - 1), n - 1) / (FRAME_EVERY * DT_S)


METHODS: dict[str, Method] = {
    "paper 000 (SfM + R3xS1 filter)": run_paper000,
    "paper 003 (angles + 1 SfM distance)": run_paper003,
    "paper 002 (distributed gradient + 1 SfM range)": run_paper002,
    "paper 001 (centralized EKF)": run_paper001,
}


# ---------------------------------------------------------------------------------------------
# Metrics and the table
# ---------------------------------------------------------------------------------------------


def rigid_error_m(est: FloatArray, true: FloatArray) -> float:
    """RMS position error after the best rigid alignment (Kabsch, proper rotation, no scale)."""
    a, b = est - est.mean(axis=0), true - true.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    dfix = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ dfix @ vt
    return float(np.sqrt(np.mean(np.sum((a @ r - b) ** 2, axis=1))))


def scale_error(est: FloatArray, true: FloatArray) -> float:
    """RMS distance to the centroid, estimate over truth, minus 1."""
    a, b = est - est.mean(axis=0), true - true.mean(axis=0)
    return float(np.sqrt(np.sum(a * a) / np.sum(b * b)) - 1.0)


def evaluate(w: Work, method: Method) -> dict[str, float]:
    t0 = time.process_time()
    est, bps = method(w)
    cpu = time.process_time() - t0
    true = w.p_ned[::FRAME_EVERY]
    if not np.all(np.isfinite(est)):
        return {"position_error_m": math.nan, "scale_error": math.nan, "time_to_scale_s": math.nan,
                "cpu_us_per_agent_step": cpu / (w.n * len(w.v_meas)) * 1e6, "bytes_per_s": bps}  # fmt: skip
    s_err = np.array([abs(scale_error(e, p)) for e, p in zip(est, true, strict=True)])
    bad = np.flatnonzero(s_err >= SCALE_TOL)
    if len(bad) == len(s_err) or (len(bad) and bad[-1] == len(s_err) - 1):
        t_scale = math.nan
    else:
        t_scale = (0 if len(bad) == 0 else bad[-1] + 1) * FRAME_EVERY * DT_S
    return {
        "position_error_m": rigid_error_m(est[-1], true[-1]),
        "scale_error": float(s_err[-1]),
        "time_to_scale_s": t_scale,
        "cpu_us_per_agent_step": cpu / (w.n * len(w.v_meas)) * 1e6,
        "bytes_per_s": bps,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--n", type=int, nargs="+", default=[3, 6, 10])
    ap.add_argument("--noise-deg", type=float, nargs="+", default=[0.0, 1.0, 2.0])
    ap.add_argument("--loss", type=float, nargs="+", default=[0.0, 0.1])
    ap.add_argument("--duration-s", type=float, default=30.0)
    ap.add_argument("--methods", nargs="+", default=None, help="substrings of method names")
    ap.add_argument("--json", default=None, help="write every run here")
    args = ap.parse_args(argv)
    methods = {
        k: m for k, m in METHODS.items() if not args.methods or any(s in k for s in args.methods)
    }
    rows = []
    for n in args.n:
        for noise in args.noise_deg:
            for loss in args.loss:
                runs: dict[str, list[dict[str, float]]] = {k: [] for k in methods}
                for seed in range(args.seeds):
                    work = make_work(n, seed, noise, loss, args.duration_s)
                    for name, m in methods.items():
                        runs[name].append(evaluate(work, m))
                for name, rs in runs.items():
                    med = {key: float(np.nanmedian([r[key] for r in rs])) if any(np.isfinite(r[key]) for r in rs) else math.nan for key in rs[0]}  # fmt: skip
                    reached = sum(math.isfinite(r["time_to_scale_s"]) for r in rs)
                    row = {"method": name, "n": n, "noise_deg": noise, "loss": loss, **med,
                           "reached_2pct": f"{reached}/{len(rs)}", "runs": rs}  # fmt: skip
                    rows.append(row)
                    print(
                        f"| {name} | {n} | {noise:g} | {loss:g} | {med['position_error_m']:.3f} | "
                        f"{med['scale_error']:.4f} | {med['time_to_scale_s']:.1f} ({reached}/{len(rs)}) | "
                        f"{med['cpu_us_per_agent_step']:.0f} | {med['bytes_per_s']:.0f} |",
                        flush=True,
                    )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

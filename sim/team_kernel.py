"""Paper 000's whole team in one compiled loop: the kernel of :mod:`sim.compiled_runner`.

:func:`simulate` steps the world of :mod:`sim.runner` and, for every vehicle, what
:class:`onboard.agent.AgentCore` does in modes ``active``, ``random``, ``formation`` and
``formation-active``, in the same order and with the same equations. It is compiled with
numba: a Python core step costs 0.16 ms (six of them every 2 ms is about real time), and the
issue-3 target of 20x real time leaves 17 us per vehicle and step.

The math is not written twice: the pure float functions of the onboard modules (the observer
rates of eq. 8, the localization gradients of eq. 6, the soft minimum and eq. 12-16) are
compiled here as they are (``njit(function)``). What is written again is the orchestration,
with arrays where the core has dictionaries and payloads:

* **messages** are per-sender values published each step into a ring of ``delay + 1`` slots;
  the receiver copies slot ``k - delay`` (``delay = 1 + round(latency / dt)``, as the runner
  delivers payloads), each copy lost with probability ``loss``, and keeps the newest copy of
  each kind per neighbour, with its stamp, as the core does;
* **the excitation table** is relayed as stamps only: the excitation of edge ``k`` stamped at
  step ``s`` is the one value its owner computed then (``lam_hist[s, k]``);
* **the SfM observers** advance, as in ``AgentCore._advance_sfm``, to the newest instant at
  which the own odometry, the peer's motion and a camera frame are all known, replaying the
  instants in between with the frames taken at them and the peer's motion interpolated
  between received samples (:mod:`onboard.estimation.time_alignment` on a lock-step clock).

Without message loss the two engines agree to round-off (``tests/sim/test_compiled_runner.py``).
Not supported (the wrapper refuses them): camera latency, field of view, ranges, targets and
the rigidity layer.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from onboard import agent as _agent
from onboard.control import active_scale as _act
from onboard.estimation import localization as _loc
from onboard.estimation import relative_yaw as _ryaw
from onboard.estimation import sfm_observer as _sfm

# the onboard modules' pure functions, compiled unchanged
excitation = njit(cache=True)(_sfm.excitation)
bearing_rate = njit(cache=True)(_sfm.bearing_rate)
observer_rates = njit(cache=True)(_sfm.observer_rates)
bearing_term_gradient = njit(cache=True)(_loc.bearing_term_gradient)
distance_term_gradient = njit(cache=True)(_loc.distance_term_gradient)
is_usable_pair = njit(cache=True)(_ryaw.is_usable_pair)
soft_min_weight = njit(cache=True)(_act.soft_min_weight)
excitation_gradient = njit(cache=True)(_act.excitation_gradient)
active_velocity_rate = njit(cache=True)(_act.active_velocity_rate)
rotation_velocity_body = njit(cache=True)(_act.rotation_velocity_body)
convergence_gain = njit(cache=True)(_act.convergence_gain)
rotation_rate_derivative = njit(cache=True)(_act.rotation_rate_derivative)

LAMBDA_FLOOR = _act.LAMBDA_FLOOR
MAX_GAP_S = _agent.MAX_ODOMETRY_GAP_S
PAIR_HISTORY = 16
"""Own frames a relative-yaw tracker keeps for pairing (``RelativeYawEdge.history``)."""
YAW_GAIN = 0.2
"""Weight of a new pair in the relative-yaw offset filter (``RelativeYawEdge.gain``)."""

MODE_CODES = {"active": 0, "random": 1, "formation": 2, "formation-active": 3}
# consensus payload layout: stamp, e_index (x, z), p_bar (x, z), dlambda/dw_l (x, z), w_l
C_STAMP, C_XE, C_ZE, C_XP, C_ZP, C_XD, C_ZD, C_WL, C_LEN = 0, 1, 2, 3, 6, 9, 10, 11, 12


@njit(cache=True)
def wrap(a: float) -> float:
    """``math.remainder(a, tau)``: the angle in ``[-pi, pi]``."""
    return a - math.tau * round(a / math.tau)


@njit(cache=True)
def predict_bearing(beta, chi, u_ij, w_i, dt):
    """:func:`onboard.estimation.sfm_observer.predict_bearing` (its callee compiled here)."""
    d = bearing_rate(beta, chi, u_ij, w_i)
    x, y, z = beta[0] + dt * d[0], beta[1] + dt * d[1], beta[2] + dt * d[2]
    n = math.sqrt(x * x + y * y + z * z)
    return (x / n, y / n, z / n)


@njit(cache=True)
def rotz(psi, v0, v1, v2):
    c, s = math.cos(psi), math.sin(psi)
    return (c * v0 - s * v1, s * v0 + c * v1, v2)


@njit(cache=True)
def yaw_offset(b_ij, b_ji, yaw_i, yaw_j):
    """:func:`onboard.estimation.relative_yaw.yaw_offset` (``math.remainder`` is not in numba)."""
    psi = (math.atan2(-b_ij[1], -b_ij[0]) - math.atan2(b_ji[1], b_ji[0]) + math.pi) % math.tau
    return wrap(psi - math.pi - (yaw_j - yaw_i))


@njit(cache=True)
def simulate(
    g,
    mode,
    n_steps,
    dt,
    frame_every,
    delay,
    record_every,
    relay_every,
    window_s,
    adj,
    pair_ends,
    des,
    has_des,
    des_yaw,
    use_des_yaw,
    p,
    yaw,
    yaw_offsets,
    p_hat,
    yaw_hat,
    chi,
    u_cmd,
    rand_z,
    rand_noise,
    speed,
    bearing_noise,
    sigma_b,
    vel_noise,
    noise_v,
    noise_w,
    lag_v,
    lag_w,
    loss,
    loss_rng,
    rec_t,
    rec_p,
    rec_yaw,
    rec_v,
    rec_p_hat,
    rec_yaw_hat,
    rec_chi,
    rec_lam,
    rec_e,
    rec_ke,
    rec_wl,
):
    """Run the team for ``n_steps + 1`` steps (``loss_rng``: a ``numpy.random.Generator``); fills the ``rec_*`` arrays (every
    ``record_every`` steps). ``g`` holds the gains (:class:`sim.compiled_runner.Gains`).
    State arrays passed in (``p, yaw, p_hat, yaw_hat, chi, u_cmd, rand_z``) are advanced in
    place."""
    n = p.shape[0]
    n_pairs = pair_ends.shape[0]
    ring = delay + 1
    tout = g.timeout
    comm = adj | adj.T
    recip = adj & adj.T
    pair_of = np.full((n, n), -1, np.int64)
    for kk in range(n_pairs):
        pair_of[pair_ends[kk, 0], pair_ends[kk, 1]] = kk
        pair_of[pair_ends[kk, 1], pair_ends[kk, 0]] = kk

    # ---- published payloads, one ring slot per step: [slot, sender, ...]
    pub_mot = np.zeros((ring, n, 6))  # stamp, u (3), w, odometry yaw
    pub_loc = np.zeros((ring, n, 5))  # stamp, phat (3), psihat
    pub_bear = np.zeros((ring, n, 2))  # stamp, odometry yaw at capture
    pub_bear_has = np.zeros((ring, n), np.bool_)
    pub_beta = np.zeros((ring, n, n, 3))  # beta_ij per target j
    pub_sfm = np.zeros((ring, n_pairs))  # chihat carried to the step
    pub_sfm_has = np.zeros((ring, n_pairs), np.bool_)
    pub_tab = np.full((ring, n, n_pairs), -1, np.int64)  # excitation stamps (steps)
    pub_cons = np.zeros((ring, n, C_LEN))
    # ---- what each agent holds of each neighbour: [receiver, sender, ...]
    mot_in = np.zeros((n, n, 6))
    mot_has = np.zeros((n, n), np.bool_)
    loc_in = np.zeros((n, n, 5))
    loc_has = np.zeros((n, n), np.bool_)
    bin_in = np.zeros((n, n, 4))  # stamp, beta_ji
    bin_has = np.zeros((n, n), np.bool_)
    sfm_in = np.zeros((n, n))
    sfm_has = np.zeros((n, n), np.bool_)
    cons_in = np.zeros((n, n, C_LEN))
    cons_has = np.zeros((n, n), np.bool_)
    tab = np.full((n, n_pairs), -(1 << 40), np.int64)
    lam_hist = np.zeros((n_steps + 1, n_pairs))
    # ---- own data: bearings, frames, odometry, relative yaws
    beta_out = np.zeros((n, n, 3))
    bout_has = np.zeros((n, n), np.bool_)
    max_gap_s = MAX_GAP_S
    hist = int(tout / dt) + frame_every + delay + 2  # instants an observer may replay
    fring = hist // frame_every + 2
    own_u = np.zeros((hist, n, 5))  # u (3), w, odometry yaw
    fr_step = np.full((n, fring), -1, np.int64)
    fr_yaw = np.zeros((n, fring))
    fr_beta = np.zeros((n, fring, n, 3))
    y_cos = np.zeros((n, n))
    y_sin = np.zeros((n, n))
    y_off = np.zeros((n, n))
    y_has = np.zeros((n, n), np.bool_)
    # ---- SfM observers, one per reciprocal pair, run by its lower id
    bh = np.zeros((n_pairs, 3))
    bp = np.zeros((n_pairs, 3))
    b_has = np.zeros(n_pairs, np.bool_)
    exc = np.zeros(n_pairs)
    e_idx = np.zeros(n_pairs)
    e_folds = np.zeros(n_pairs)
    t_obs = np.full(n_pairs, -np.inf)
    chi_rate = np.zeros(n_pairs)
    last_inst = np.full(n_pairs, -1, np.int64)
    applied = np.full(n_pairs, -(1 << 40), np.int64)  # newest frame step the observer took
    pm = np.zeros((n_pairs, hist, 6))  # the peer's received motion per instant
    pm_step = np.full((n_pairs, hist), -1, np.int64)
    pm_newest = np.full(n_pairs, -1, np.int64)
    win_len = int(window_s / dt) + 3  # ring of the samples inside the window, and spare
    win = np.zeros((n_pairs, win_len))
    win_k = np.full((n_pairs, win_len), -1, np.int64)
    win_old = np.zeros(n_pairs, np.int64)  # oldest instant that may still be in the window
    win_sum = np.zeros(n_pairs)
    # ---- consensus and control
    ce = np.zeros((n, 2))  # e_index: x, z
    cp = np.zeros((n, 2, 3))  # p_bar: x, z
    cd = np.zeros((n, 2))  # dlambdabar/dw_l: x, z
    c_init = np.zeros(n, np.bool_)
    lam_bar = np.zeros(n)
    e_index = np.zeros(n)
    k_e = np.zeros(n)
    w_l = np.zeros(n)
    sp = np.zeros((n, 4))  # setpoints: u (3), w
    rel = np.zeros((n, n, 3))
    rel_has = np.zeros((n, n), np.bool_)
    dx_p = np.zeros(3)
    dz_p = np.zeros(3)
    # ---- world
    v_body = np.zeros((n, 3))
    w_body = np.zeros(n)
    v_ned = np.zeros((n, 3))
    beta_now = np.zeros((n, n, 3))
    r_idx = 0
    frame_no = 0

    for k in range(n_steps + 1):
        t = k * dt
        slot = k % ring
        src = (k - delay) % ring
        have_src = k >= delay
        # ---------------------------------------------------- camera frame (truth -> bearings)
        frame = k % frame_every == 0
        if frame:
            e = 0
            for i in range(n):
                c, s = math.cos(yaw[i]), math.sin(yaw[i])
                for j in range(n):
                    if not adj[i, j]:
                        continue
                    r0, r1, r2 = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1], p[j, 2] - p[i, 2]
                    d = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
                    b0, b1, b2 = (c * r0 + s * r1) / d, (-s * r0 + c * r1) / d, r2 / d
                    if sigma_b > 0.0:
                        z0 = sigma_b * bearing_noise[frame_no, e, 0]
                        z1 = sigma_b * bearing_noise[frame_no, e, 1]
                        z2 = sigma_b * bearing_noise[frame_no, e, 2]
                        zb = z0 * b0 + z1 * b1 + z2 * b2  # tangent plane
                        b0, b1, b2 = b0 + z0 - zb * b0, b1 + z1 - zb * b1, b2 + z2 - zb * b2
                        nb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
                        b0, b1, b2 = b0 / nb, b1 / nb, b2 / nb
                    beta_now[i, j, 0], beta_now[i, j, 1], beta_now[i, j, 2] = b0, b1, b2
                    e += 1
            frame_no += 1

        # ---------------------------------------------------- 1. inbox: slot k - delay
        if have_src:
            for i in range(n):
                for j in range(n):
                    if not comm[i, j]:
                        continue
                    if loss == 0.0 or loss_rng.random() >= loss:
                        mot_in[i, j] = pub_mot[src, j]
                        mot_has[i, j] = True
                        kk = pair_of[i, j]
                        if kk >= 0 and pair_ends[kk, 0] == i:  # an observer's input
                            pm[kk, (k - delay) % hist] = pub_mot[src, j]
                            pm_step[kk, (k - delay) % hist] = k - delay
                            pm_newest[kk] = k - delay
                    if loss == 0.0 or loss_rng.random() >= loss:
                        loc_in[i, j] = pub_loc[src, j]
                        loc_has[i, j] = True
                    if loss == 0.0 or loss_rng.random() >= loss:
                        cons_in[i, j] = pub_cons[src, j]
                        cons_has[i, j] = True
                    if loss == 0.0 or loss_rng.random() >= loss:
                        for kk in range(n_pairs):
                            st = pub_tab[src, j, kk]
                            if st > tab[i, kk]:
                                tab[i, kk] = st
                    kk = pair_of[i, j]
                    if kk >= 0 and pair_ends[kk, 0] == j and pub_sfm_has[src, kk]:
                        if loss == 0.0 or loss_rng.random() >= loss:
                            sfm_in[i, j] = pub_sfm[src, kk]
                            sfm_has[i, j] = True
                    if pub_bear_has[src, j] and (loss == 0.0 or loss_rng.random() >= loss):
                        stamp = pub_bear[src, j, 0]
                        if adj[j, i] and (not bin_has[i, j] or stamp > bin_in[i, j, 0]):
                            bin_in[i, j, 0] = stamp
                            bin_in[i, j, 1:] = pub_beta[src, j, i]
                            bin_has[i, j] = True
                            # relative yaw: pair with the own frame of the same stamp
                            f = (k - delay) // frame_every % fring
                            if recip[i, j] and fr_step[i, f] == k - delay:
                                b_ij = (
                                    fr_beta[i, f, j, 0],
                                    fr_beta[i, f, j, 1],
                                    fr_beta[i, f, j, 2],
                                )
                                b_ji = (bin_in[i, j, 1], bin_in[i, j, 2], bin_in[i, j, 3])
                                if is_usable_pair(b_ij, b_ji, 0.1):
                                    off = yaw_offset(b_ij, b_ji, fr_yaw[i, f], pub_bear[src, j, 1])
                                    co, so = math.cos(off), math.sin(off)
                                    if y_has[i, j]:
                                        y_cos[i, j] += YAW_GAIN * (co - y_cos[i, j])
                                        y_sin[i, j] += YAW_GAIN * (so - y_sin[i, j])
                                    else:
                                        y_cos[i, j], y_sin[i, j] = co, so
                                    y_off[i, j] = math.atan2(y_sin[i, j], y_cos[i, j])
                                    y_has[i, j] = True

        # ---------------------------------------------------- per agent: AgentCore.step
        for i in range(n):
            # 2. own measurements (odometry yaw with its unknown offset)
            u0, u1, u2, w_i = v_body[i, 0], v_body[i, 1], v_body[i, 2], w_body[i]
            if noise_v > 0.0 or noise_w > 0.0:
                u0 += noise_v * vel_noise[k, i, 0]
                u1 += noise_v * vel_noise[k, i, 1]
                u2 += noise_v * vel_noise[k, i, 2]
                w_i += noise_w * vel_noise[k, i, 3]
            yaw_own = yaw[i] + yaw_offsets[i]
            own_u[k % hist, i, 0], own_u[k % hist, i, 1], own_u[k % hist, i, 2] = u0, u1, u2
            own_u[k % hist, i, 3], own_u[k % hist, i, 4] = w_i, yaw_own
            # 3. a camera frame: keep it, share it
            pub_bear_has[slot, i] = frame
            if frame:
                f = k // frame_every % fring
                fr_step[i, f] = k
                fr_yaw[i, f] = yaw_own
                pub_bear[slot, i, 0], pub_bear[slot, i, 1] = t, yaw_own
                for j in range(n):
                    if adj[i, j]:
                        beta_out[i, j] = beta_now[i, j]
                        bout_has[i, j] = True
                        fr_beta[i, f, j] = beta_now[i, j]
                        pub_beta[slot, i, j] = beta_now[i, j]
            # 4. relative velocity on reciprocal edges (eq. 7)
            for j in range(n):
                rel_has[i, j] = False
                if not (recip[i, j] and mot_has[i, j] and y_has[i, j]):
                    continue
                m = mot_in[i, j]
                if t - m[0] > tout:
                    continue
                psi = wrap(m[5] + m[4] * (t - m[0]) - yaw_own + y_off[i, j])
                uj = rotz(psi, m[1], m[2], m[3])
                rel[i, j, 0], rel[i, j, 1], rel[i, j, 2] = uj[0] - u0, uj[1] - u1, uj[2] - u2
                rel_has[i, j] = True

        # 5. SfM observers (eq. 8, 10), run by the lower id: as AgentCore._advance_sfm, each
        # advances to the newest instant tau1 at which its inputs are known (own odometry, the
        # peer's motion, a camera frame), replaying the instants in between
        for kk in range(n_pairs):
            pub_sfm_has[slot, kk] = False
            a, b = pair_ends[kk, 0], pair_ends[kk, 1]
            newest_frame = max(k - k % frame_every, applied[kk])
            tau1 = min(k, pm_newest[kk], newest_frame)
            if tau1 < 0 or t - tau1 * dt > tout or not y_has[a, b]:
                continue
            tau0 = last_inst[kk] if last_inst[kk] >= 0 else tau1
            if (tau1 - tau0) * dt > tout:  # after a gap: restart, do not integrate
                tau0 = tau1
                b_has[kk] = False
            pub_sfm_has[slot, kk] = True
            if tau1 < tau0:
                continue
            if last_inst[kk] < 0 or tau0 == tau1:
                # frames left over from before the start: keep the newest one <= tau0
                applied[kk] = max(applied[kk], tau0 - tau0 % frame_every - frame_every)
            last_inst[kk] = tau1
            for s_inst in range(tau0 + 1, tau1 + 1):
                ts = s_inst * dt
                mine = own_u[s_inst % hist, a]
                # the peer's motion at s: linear between received samples, held after the newest
                h1 = s_inst
                while pm_step[kk, h1 % hist] != h1 and h1 > s_inst - hist + 1:
                    h1 -= 1
                if pm_step[kk, h1 % hist] != h1:
                    continue
                m0 = pm[kk, h1 % hist]
                yaw_j, mj0, mj1, mj2 = m0[5], m0[1], m0[2], m0[3]
                gap = s_inst - h1
                if h1 < s_inst and h1 < pm_newest[kk]:
                    h2 = s_inst + 1
                    while pm_step[kk, h2 % hist] != h2:
                        h2 += 1
                    m1 = pm[kk, h2 % hist]
                    fa = (s_inst - h1) / (h2 - h1)
                    mj0 = m0[1] + fa * (m1[1] - m0[1])
                    mj1 = m0[2] + fa * (m1[2] - m0[2])
                    mj2 = m0[3] + fa * (m1[3] - m0[3])
                    yaw_j = m0[5] + fa * wrap(m1[5] - m0[5])
                    gap = h2 - h1
                if gap * dt > max_gap_s:
                    # a hole in the peer's odometry: do not integrate across it, restart after it
                    b_has[kk] = False
                    applied[kk] = max(applied[kk], s_inst - s_inst % frame_every)
                    continue
                psi = wrap(yaw_j - mine[4] + y_off[a, b])
                uj = rotz(psi, mj0, mj1, mj2)
                u_ij = (uj[0] - mine[0], uj[1] - mine[1], uj[2] - mine[2])
                w_a = mine[3]
                f_step = applied[kk] + frame_every
                while f_step <= s_inst:  # frames taken up to s, predicted to s
                    f = f_step // frame_every % fring
                    if fr_step[a, f] == f_step:
                        beta = (fr_beta[a, f, b, 0], fr_beta[a, f, b, 1], fr_beta[a, f, b, 2])
                        q = predict_bearing(beta, chi[kk], u_ij, w_a, ts - f_step * dt)
                        bp[kk, 0], bp[kk, 1], bp[kk, 2] = q[0], q[1], q[2]
                        if not b_has[kk]:
                            bh[kk] = bp[kk]
                            b_has[kk] = True
                    applied[kk] = f_step
                    f_step += frame_every
                if not b_has[kk]:
                    continue
                beta_p = (bp[kk, 0], bp[kk, 1], bp[kk, 2])
                beta_h = (bh[kk, 0], bh[kk, 1], bh[kk, 2])
                d_bh, d_chi = observer_rates(
                    beta_h, chi[kk], beta_p, u_ij, w_a, g.alpha, g.h_other, g.h_floor
                )
                x0, x1, x2 = beta_h[0] - beta_p[0], beta_h[1] - beta_p[1], beta_h[2] - beta_p[2]
                exc[kk] = excitation(beta_p, u_ij)
                e_folds[kk] += dt * math.sqrt(g.alpha * exc[kk])
                # E_ij (eq. 10): WindowAverage.add, samples in (ts - T, ts], same float order
                wslot = s_inst % win_len
                if win_k[kk, wslot] >= win_old[kk]:  # after a long hole: an old sample left
                    win_sum[kk] -= win[kk, wslot]
                win[kk, wslot] = (x0 * x0 + x1 * x1 + x2 * x2) * dt
                win_k[kk, wslot] = s_inst
                win_sum[kk] += win[kk, wslot]
                while win_old[kk] <= s_inst and win_old[kk] * dt <= ts - window_s:
                    if win_k[kk, win_old[kk] % win_len] == win_old[kk]:
                        win_sum[kk] -= win[kk, win_old[kk] % win_len]
                    win_old[kk] += 1
                e_idx[kk] = max(win_sum[kk], 0.0) / window_s
                q = predict_bearing(beta_p, chi[kk], u_ij, w_a, dt)
                bp[kk, 0], bp[kk, 1], bp[kk, 2] = q[0], q[1], q[2]
                bh[kk, 0] = beta_h[0] + dt * d_bh[0]
                bh[kk, 1] = beta_h[1] + dt * d_bh[1]
                bh[kk, 2] = beta_h[2] + dt * d_bh[2]
                chi[kk] += dt * d_chi
                t_obs[kk] = ts
                u_b = u_ij[0] * q[0] + u_ij[1] * q[1] + u_ij[2] * q[2]
                chi_rate[kk] = -chi[kk] * chi[kk] * u_b
            pub_sfm[slot, kk] = chi[kk] + min(max(t - t_obs[kk], 0.0), tout) * chi_rate[kk]

        for i in range(n):
            u0, u1, u2 = own_u[k % hist, i, 0], own_u[k % hist, i, 1], own_u[k % hist, i, 2]
            w_i = own_u[k % hist, i, 3]
            # 6. localization filter (eq. 6): own bearings, neighbours' bearings, SfM distances
            pi_ = (p_hat[i, 0], p_hat[i, 1], p_hat[i, 2])
            g0 = g1 = g2 = g_yaw = 0.0
            d0 = d1 = d2 = 0.0
            for j in range(n):
                if not loc_has[i, j]:
                    continue
                lj = loc_in[i, j]
                pj = (lj[1], lj[2], lj[3])
                fresh = t - lj[0] <= tout
                if fresh and adj[i, j] and bout_has[i, j]:
                    beta = (beta_out[i, j, 0], beta_out[i, j, 1], beta_out[i, j, 2])
                    gi, gy, _ = bearing_term_gradient(pi_, yaw_hat[i], pj, beta)
                    g0, g1, g2, g_yaw = g0 + gi[0], g1 + gi[1], g2 + gi[2], g_yaw + gy
                if fresh and adj[j, i] and bin_has[i, j]:
                    beta = (bin_in[i, j, 1], bin_in[i, j, 2], bin_in[i, j, 3])
                    _, _, gj = bearing_term_gradient(pj, lj[4], pi_, beta)
                    g0, g1, g2 = g0 + gj[0], g1 + gj[1], g2 + gj[2]
                if recip[i, j]:  # SfM distance (the core uses a stale neighbour estimate too)
                    kk = pair_of[i, j]
                    if pair_ends[kk, 0] == i:
                        c_ij = chi[kk] + min(max(t - t_obs[kk], 0.0), tout) * chi_rate[kk]
                        ok = True
                    else:
                        c_ij, ok = sfm_in[i, j], sfm_has[i, j]
                    if ok and c_ij >= g.chi_min:
                        gd = distance_term_gradient(pi_, pj, 1.0 / c_ij)
                        d0, d1, d2 = d0 + gd[0], d1 + gd[1], d2 + gd[2]
            kl, kd = g.k_loc_b, g.k_loc_d
            f0, f1, f2 = kl * g0 + kd * d0, kl * g1 + kd * d1, kl * g2 + kd * d2
            fn = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
            if fn > g.loc_max_m_s:
                f0, f1, f2 = (
                    f0 * g.loc_max_m_s / fn,
                    f1 * g.loc_max_m_s / fn,
                    f2 * g.loc_max_m_s / fn,
                )
            f_yaw = max(-g.loc_max_rad_s, min(g.loc_max_rad_s, kl * g_yaw))
            c, s = math.cos(yaw_hat[i]), math.sin(yaw_hat[i])
            dtk = dt if k > 0 else 0.0
            p_hat[i, 0] = pi_[0] + dtk * (c * u0 - s * u1 - f0)
            p_hat[i, 1] = pi_[1] + dtk * (s * u0 + c * u1 - f1)
            p_hat[i, 2] = pi_[2] + dtk * (u2 - f2)
            yaw_hat[i] = wrap(yaw_hat[i] + dtk * (w_i - f_yaw))

            # 7. lambdabar (eq. 11) from the fresh excitation table; relay it
            for kk in range(n_pairs):
                if pair_ends[kk, 0] == i and b_has[kk]:
                    lam_hist[k, kk] = exc[kk]
                    tab[i, kk] = k
            acc = 0.0
            any_fresh = False
            for kk in range(n_pairs):
                st = tab[i, kk]
                pub_tab[slot, i, kk] = -1
                if st >= 0 and t - st * dt <= tout:
                    acc += max(lam_hist[st, kk], LAMBDA_FLOOR) ** g.p_norm
                    any_fresh = True
                    if k % relay_every == 0 or pair_ends[kk, 0] == i:
                        pub_tab[slot, i, kk] = st
            lam_bar[i] = acc ** (1.0 / g.p_norm) if any_fresh else 0.0
            # PI average consensus (fig. 1) of E; in case 4 also of pbar and dlambdabar/dw_l
            e_sum = 0.0
            for kk in range(n_pairs):
                if pair_ends[kk, 0] == i:
                    e_sum += e_idx[kk] + (g.e_high if e_folds[kk] < g.e_folds_min else 0.0)
            # d lambdabar / d u_i (eq. 12) from the own bearings and relative velocities
            gr0 = gr1 = gr2 = 0.0
            for j in range(n):
                if rel_has[i, j] and bout_has[i, j]:
                    beta = (beta_out[i, j, 0], beta_out[i, j, 1], beta_out[i, j, 2])
                    u_ij = (rel[i, j, 0], rel[i, j, 1], rel[i, j, 2])
                    wgt = soft_min_weight(excitation(beta, u_ij), lam_bar[i], g.p_norm)
                    dg = excitation_gradient(beta, u_ij)
                    gr0, gr1, gr2 = gr0 + wgt * dg[0], gr1 + wgt * dg[1], gr2 + wgt * dg[2]
            case4 = mode == 3
            if not c_init[i]:  # PIConsensus starts at its first input
                ce[i, 0], ce[i, 1] = e_sum, 0.0
                for m3 in range(3):
                    cp[i, 0, m3], cp[i, 1, m3] = p_hat[i, m3], 0.0
            dx_e = g.cons_gamma * (e_sum - ce[i, 0])
            dz_e = 0.0
            for m3 in range(3):
                dx_p[m3] = g.cons_gamma * (p_hat[i, m3] - cp[i, 0, m3])
                dz_p[m3] = 0.0
            for j in range(n):
                if not (comm[i, j] and cons_has[i, j] and t - cons_in[i, j, C_STAMP] <= tout):
                    continue
                cj = cons_in[i, j]
                dxm = ce[i, 0] - cj[C_XE]
                dx_e += -g.cons_kp * dxm + g.cons_ki * (ce[i, 1] - cj[C_ZE])
                dz_e -= g.cons_ki * dxm
                if case4:
                    for m3 in range(3):
                        dxm = cp[i, 0, m3] - cj[C_XP + m3]
                        dx_p[m3] += -g.cons_kp * dxm + g.cons_ki * (cp[i, 1, m3] - cj[C_ZP + m3])
                        dz_p[m3] -= g.cons_ki * dxm
            ce[i, 0] += dtk * dx_e
            ce[i, 1] += dtk * dz_e
            e_index[i] = max(n * ce[i, 0], 0.0)
            n3 = (0.0, 0.0, 0.0)
            if case4:
                for m3 in range(3):
                    cp[i, 0, m3] += dtk * dx_p[m3]
                    cp[i, 1, m3] += dtk * dz_p[m3]
                n3 = rotation_velocity_body(
                    (p_hat[i, 0], p_hat[i, 1], p_hat[i, 2]),
                    yaw_hat[i],
                    (cp[i, 0, 0], cp[i, 0, 1], cp[i, 0, 2]),
                )
                delta = gr0 * n3[0] + gr1 * n3[1] + gr2 * n3[2]
                if not c_init[i]:
                    cd[i, 0], cd[i, 1] = delta, 0.0
                dx_d = g.cons_gamma * (delta - cd[i, 0])
                dz_d = 0.0
                for j in range(n):
                    if comm[i, j] and cons_has[i, j] and t - cons_in[i, j, C_STAMP] <= tout:
                        cj = cons_in[i, j]
                        dxm = cd[i, 0] - cj[C_XD]
                        dx_d += -g.cons_kp * dxm + g.cons_ki * (cd[i, 1] - cj[C_ZD])
                        dz_d -= g.cons_ki * dxm
                cd[i, 0] += dtk * dx_d
                cd[i, 1] += dtk * dz_d
            c_init[i] = True

            # 8. control
            if mode == 0:  # active perception, eq. 12
                uc = (u_cmd[i, 0], u_cmd[i, 1], u_cmd[i, 2])
                du = active_velocity_rate(uc, (gr0, gr1, gr2), g.k_nu, g.nu_star, g.k_lambda)
                for m3 in range(3):
                    u_cmd[i, m3] += dtk * du[m3]
                v0, v1, v2, w_c = u_cmd[i, 0], u_cmd[i, 1], u_cmd[i, 2], 0.0
            elif mode == 1:  # random directions at the same speed (Ornstein-Uhlenbeck)
                if k > 0:
                    aa = math.exp(-dt / g.random_tau_s)
                    bb = math.sqrt(1.0 - aa * aa)
                    for m3 in range(3):
                        rand_z[i, m3] = aa * rand_z[i, m3] + bb * rand_noise[i, k - 1, m3]
                zn = math.sqrt(rand_z[i, 0] ** 2 + rand_z[i, 1] ** 2 + rand_z[i, 2] ** 2)
                kz = speed / zn if zn > 0.0 else 0.0
                v0, v1, v2, w_c = kz * rand_z[i, 0], kz * rand_z[i, 1], kz * rand_z[i, 2], 0.0
            else:  # bearing formation (paper 002 eq. 20) and yaw alignment
                a0 = a1 = a2 = 0.0
                w_f = 0.0
                for j in range(n):
                    if adj[i, j] and bout_has[i, j] and has_des[i, j]:
                        a0 += beta_out[i, j, 0] - des[i, j, 0]
                        a1 += beta_out[i, j, 1] - des[i, j, 1]
                        a2 += beta_out[i, j, 2] - des[i, j, 2]
                    if not (comm[i, j] and loc_has[i, j] and t - loc_in[i, j, 0] <= tout):
                        continue
                    yaw_j = loc_in[i, j, 4]
                    if use_des_yaw:
                        w_f += g.k_yaw * math.sin(yaw_j - yaw_hat[i] - (des_yaw[j] - des_yaw[i]))
                    if bin_has[i, j] and has_des[j, i]:
                        e0 = bin_in[i, j, 1] - des[j, i, 0]
                        e1 = bin_in[i, j, 2] - des[j, i, 1]
                        e2 = bin_in[i, j, 3] - des[j, i, 2]
                        cy, sy = math.cos(yaw_j - yaw_hat[i]), math.sin(yaw_j - yaw_hat[i])
                        a0, a1, a2 = a0 - (cy * e0 - sy * e1), a1 - (sy * e0 + cy * e1), a2 - e2
                v0, v1, v2, w_c = g.k_formation * a0, g.k_formation * a1, g.k_formation * a2, w_f
                if case4:  # bearing-constrained active perception, eq. 13-16
                    k_e[i] = convergence_gain(e_index[i], g.e_low, g.e_high)
                    dw = rotation_rate_derivative(
                        w_l[i], n * cd[i, 0], lam_bar[i], k_e[i], g.k_w, g.k_lambda0, g.gamma
                    )
                    for j in range(n):
                        if comm[i, j] and cons_has[i, j] and t - cons_in[i, j, C_STAMP] <= tout:
                            dw += g.k_wl_coupling * (cons_in[i, j, C_WL] - w_l[i])
                    w_l[i] = max(-g.w_l_max, min(g.w_l_max, w_l[i] + dtk * dw))
                    v0, v1, v2 = v0 + w_l[i] * n3[0], v1 + w_l[i] * n3[1], v2 + w_l[i] * n3[2]
                    w_c += w_l[i]
            vn = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            if vn > g.v_max:
                v0, v1, v2 = v0 * g.v_max / vn, v1 * g.v_max / vn, v2 * g.v_max / vn
            sp[i, 0], sp[i, 1], sp[i, 2] = v0, v1, v2
            sp[i, 3] = max(-g.w_max, min(g.w_max, w_c))

            # 9. publish: consensus, motion, localization
            pc = pub_cons[slot, i]
            pc[C_STAMP], pc[C_XE], pc[C_ZE] = t, ce[i, 0], ce[i, 1]
            pc[C_XP : C_XP + 3] = cp[i, 0]
            pc[C_ZP : C_ZP + 3] = cp[i, 1]
            pc[C_XD], pc[C_ZD], pc[C_WL] = cd[i, 0], cd[i, 1], w_l[i]
            pub_mot[slot, i, 0] = t
            pub_mot[slot, i, 1:5] = own_u[k % hist, i, 0:4]
            pub_mot[slot, i, 5] = own_u[k % hist, i, 4]
            pub_loc[slot, i, 0] = t
            pub_loc[slot, i, 1:4] = p_hat[i]
            pub_loc[slot, i, 4] = yaw_hat[i]

        # ---------------------------------------------------- record (truth and estimates)
        if k % record_every == 0:
            rec_t[r_idx] = t
            for i in range(n):
                c, s = math.cos(yaw[i]), math.sin(yaw[i])
                rec_p[r_idx, i] = p[i]
                rec_yaw[r_idx, i] = yaw[i]
                rec_v[r_idx, i, 0] = c * v_body[i, 0] - s * v_body[i, 1]
                rec_v[r_idx, i, 1] = s * v_body[i, 0] + c * v_body[i, 1]
                rec_v[r_idx, i, 2] = v_body[i, 2]
                rec_p_hat[r_idx, i] = p_hat[i]
                rec_yaw_hat[r_idx, i] = yaw_hat[i]
                rec_lam[r_idx, i] = lam_bar[i]
                rec_e[r_idx, i] = e_index[i]
                rec_ke[r_idx, i] = k_e[i]
                rec_wl[r_idx, i] = w_l[i]
            for kk in range(n_pairs):
                rec_chi[r_idx, kk] = chi[kk] + min(max(t - t_obs[kk], 0.0), tout) * chi_rate[kk]
            r_idx += 1

        # ---------------------------------------------------- world (paper 000 eq. 1, Euler)
        for i in range(n):
            c, s = math.cos(yaw[i]), math.sin(yaw[i])
            v0 = c * sp[i, 0] - s * sp[i, 1]
            v1 = s * sp[i, 0] + c * sp[i, 1]
            v2 = sp[i, 2]
            w = sp[i, 3]
            if lag_v > 0.0:
                v0 = v_ned[i, 0] + lag_v * (v0 - v_ned[i, 0])
                v1 = v_ned[i, 1] + lag_v * (v1 - v_ned[i, 1])
                v2 = v_ned[i, 2] + lag_v * (v2 - v_ned[i, 2])
            if lag_w > 0.0:
                w = w_body[i] + lag_w * (w - w_body[i])
            v_ned[i, 0], v_ned[i, 1], v_ned[i, 2] = v0, v1, v2
            p[i, 0] += dt * v0
            p[i, 1] += dt * v1
            p[i, 2] += dt * v2
            yaw[i] += dt * w
            c, s = math.cos(yaw[i]), math.sin(yaw[i])
            v_body[i, 0] = c * v0 + s * v1
            v_body[i, 1] = -s * v0 + c * v1
            v_body[i, 2] = v2
            w_body[i] = w
    return r_idx

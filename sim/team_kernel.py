"""Paper 000's whole team in one compiled loop: the kernel of :mod:`sim.compiled_runner`.

:func:`simulate` steps the world of :mod:`sim.runner` and, for every vehicle, what
:class:`onboard.core.agent.AgentCore` does in modes ``active``, ``random``, ``formation``,
``formation-active`` and ``hold``, in the same order and with the same equations. It is
compiled with numba: a Python core step costs 0.16 ms (six of them every 2 ms is about real
time), and the target of 20x real time leaves 17 us per vehicle and step.

The math is written once. Every formula is a pure scalar function of the module that owns it
(``onboard/estimation``, ``onboard/control``, :mod:`sim.world`, :mod:`sim.camera`,
:mod:`sim.draws`), which the per-vehicle core calls as plain Python; here the same functions
are compiled by :func:`sim.jit.compiled` (each with its callees compiled too):

* the localization Euler step with its saturation and its edge gradients (paper 000 eq. 6),
* the PI average consensus terms (fig. 1), the soft minimum ``lambdabar`` and its gradient
  (eq. 11-12), eq. 12-16's controllers, the formation law and yaw alignment (paper 002
  eq. 20), the Ornstein-Uhlenbeck random motion,
* the SfM observer step (eq. 8), its e-foldings and window integral (eq. 10), the bearing
  prediction (eq. 7), the relative-yaw offsets and their circular filter,
* the vehicle step (eq. 1), the camera's bearing noise and the message-loss draws.

What is written again is the orchestration, with arrays where the core has dictionaries and
payloads:

* **messages** are per-sender values published each step into a ring of ``delay + 1`` slots;
  the receiver copies slot ``k - delay`` (``delay = 1 + round(latency / dt)``, as the runner
  delivers payloads), each copy lost when :func:`sim.draws.lost` says so for ``(step sent,
  sender, receiver, payload kind)`` (the runner asks the same), and keeps the newest copy of
  each kind per neighbour, with its stamp, as the core does;
* **the excitation table** is relayed as stamps only: the excitation of edge ``k`` stamped at
  step ``s`` is the one value its owner computed then (``lam_hist[s, k]``);
* **the SfM observers** advance, as in ``AgentCore._advance_sfm``, to the newest instant at
  which the own odometry, the peer's motion and a camera frame are all known, replaying the
  instants in between with the frames taken at them and the peer's motion interpolated
  between received samples (:mod:`onboard.estimation.time_alignment` on a lock-step clock).

The two engines agree to round-off, with message loss too (``tests/sim/test_compiled_runner.py``).
Not supported (the wrapper refuses them): camera latency, field of view, ranges, targets and
the rigidity layer. Inputs are four records: :class:`Team` (graph, schedule, network),
:class:`Noise` (the pre-drawn noise), :class:`State` (advanced in place) and :class:`Trace`
(filled), with the gains in :class:`sim.compiled_runner.Gains`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from onboard.control import active_scale, formation, random_motion
from onboard.estimation import consensus, localization, relative_yaw, sfm_observer
from onboard.estimation import time_alignment as time_al
from sim import camera, draws, world
from sim.jit import compiled

_sfm = compiled(sfm_observer)
_loc = compiled(localization)
_cons = compiled(consensus)
_ryaw = compiled(relative_yaw)
_act = compiled(active_scale)
_form = compiled(formation)
_rand = compiled(random_motion)
_ta = compiled(time_al)
_world = compiled(world)
_cam = compiled(camera)
_draws = compiled(draws)

excitation = _sfm.excitation
predict_bearing = _sfm.predict_bearing
observer_step = _sfm.observer_step
excitation_gate = _sfm.excitation_gate
e_fold_increment = _sfm.e_fold_increment
window_add = _sfm.window_add
bearing_term_gradient = _loc.bearing_term_gradient
distance_term_gradient = _loc.distance_term_gradient
localization_euler_step = _loc.localization_euler_step
pi_input_rate = _cons.pi_input_rate
pi_coupling_rates = _cons.pi_coupling_rates
is_usable_pair = _ryaw.is_usable_pair
yaw_offset = _ryaw.yaw_offset
relative_yaw_now = _ryaw.relative_yaw_now
filter_offset = _ryaw.filter_offset
lambda_bar_term = _act.lambda_bar_term
lambda_bar_of_sum = _act.lambda_bar_of_sum
lambda_bar_gradient_term = _act.lambda_bar_gradient_term
active_velocity_rate = _act.active_velocity_rate
rotation_velocity_body = _act.rotation_velocity_body
convergence_gain = _act.convergence_gain
rotation_rate_derivative = _act.rotation_rate_derivative
formation_out_term = _form.formation_out_term
formation_in_term = _form.formation_in_term
yaw_alignment_term = _form.yaw_alignment_term
ou_direction_step = _rand.ou_direction_step
ou_velocity = _rand.ou_velocity
interpolation_weight = _ta.interpolation_weight
lerp = _ta.lerp
lerp_angle = _ta.lerp_angle
kinematic_step = _world.kinematic_step
noisy_bearing = _cam.noisy_bearing
lost = _draws.lost

PAIR_HISTORY = relative_yaw.PAIR_HISTORY
"""Own frames a relative-yaw tracker keeps for pairing (``RelativeYawEdge.history``)."""
YAW_GAIN = relative_yaw.FILTER_GAIN
MIN_HORIZONTAL = relative_yaw.MIN_HORIZONTAL

MODE_CODES = {"active": 0, "random": 1, "formation": 2, "formation-active": 3, "hold": 4}
# consensus quantities, one column each: E (eq. 10), pbar (3), dlambdabar/dw_l (eq. 14)
Q_E, Q_P, Q_D, N_Q = 0, 1, 4, 5
# consensus payload layout: stamp, x (N_Q), z (N_Q), w_l
C_STAMP, C_X, C_Z, C_WL, C_LEN = 0, 1, 1 + N_Q, 1 + 2 * N_Q, 2 + 2 * N_Q
K_MOTION, K_LOC, K_CONS = draws.KIND_MOTION, draws.KIND_LOCALIZATION, draws.KIND_CONSENSUS
K_TAB, K_SFM, K_BEAR = draws.KIND_EXCITATION, draws.KIND_SFM, draws.KIND_BEARING


class Team(NamedTuple):
    """The team's graph, schedule and network (fixed for the run)."""

    mode: int
    """:data:`MODE_CODES`."""
    n_steps: int
    dt: float
    frame_every: int
    """Steps between camera frames."""
    delay: int
    """Steps from a payload's publication to its delivery (``1 + round(latency / dt)``)."""
    record_every: int
    relay_every: int
    """``AgentConfig.excitation_relay_every``."""
    max_odometry_gap_s: float
    """``onboard.core.bearings.MAX_ODOMETRY_GAP_S``."""
    window_s: float
    """``AgentConfig.e_window_s`` (eq. 10)."""
    adj: np.ndarray
    """``(N, N)`` bool: the sensing edges ``i -> j``."""
    pair_ends: np.ndarray
    """``(K, 2)`` int64: the reciprocal pairs ``(i, j)``, ``i < j``."""
    des: np.ndarray
    """``(N, N, 3)`` desired body bearings ``beta*_ij`` where ``has_des``."""
    has_des: np.ndarray
    des_yaw: np.ndarray
    """``(N,)`` desired yaws (used when ``use_des_yaw``)."""
    use_des_yaw: bool
    speed: float
    """``sqrt(2 nu*)``: the random-motion speed."""
    seed: int
    """Seed of the message-loss draws (:func:`sim.draws.lost`)."""
    loss: float
    lag_v: float
    """``dt / tau_v`` of the autopilot lag (0: none), :func:`sim.world.kinematic_step`."""
    lag_w: float


class Noise(NamedTuple):
    """Pre-drawn noise (the runner's streams, in its order)."""

    bearing: np.ndarray
    """``(frames, E, 3)`` standard normals per frame and sensing edge (edge order)."""
    sigma_bearing_rad: float
    odometry: np.ndarray
    """``(steps + 1, N, 4)`` standard normals: ``v_body`` x, y, z and yaw rate."""
    sigma_v_m_s: float
    sigma_w_rad_s: float
    random_motion: np.ndarray
    """``(N, steps, 3)``: :class:`onboard.control.random_motion.RandomMotion`'s draws."""


class State(NamedTuple):
    """The team's state, advanced in place."""

    p_ned: np.ndarray
    yaw_rad: np.ndarray
    yaw_offset_rad: np.ndarray
    """``(N,)`` odometry yaw offsets."""
    p_hat_ned: np.ndarray
    yaw_hat_rad: np.ndarray
    chi_hat: np.ndarray
    """``(K,)`` per reciprocal pair."""
    u_cmd: np.ndarray
    """``(N, 3)`` eq. 12's commanded body velocity."""
    rand_z: np.ndarray
    """``(N, 3)`` the random-motion direction processes."""


class Trace(NamedTuple):
    """The recorded samples (:class:`sim.runner.Recording`'s arrays), filled."""

    t_s: np.ndarray
    p_ned: np.ndarray
    yaw_rad: np.ndarray
    v_ned: np.ndarray
    p_hat_ned: np.ndarray
    yaw_hat_rad: np.ndarray
    chi_hat: np.ndarray
    lambda_bar: np.ndarray
    e_index: np.ndarray
    k_e: np.ndarray
    w_l: np.ndarray


@njit(cache=True)
def rotz(psi, v0, v1, v2):
    """``R_z(psi) v`` (``onboard.core.scale.rotz``)."""
    c, s = math.cos(psi), math.sin(psi)
    return (c * v0 - s * v1, s * v0 + c * v1, v2)


@njit(cache=True)
def saturate(v0, v1, v2, limit):
    """``v`` scaled down to norm ``limit`` where longer (``onboard.agent._saturate``)."""
    n = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    if n <= limit:
        return (v0, v1, v2)
    k = limit / n
    return (k * v0, k * v1, k * v2)


@njit(cache=True, inline="always")
def consensus_step(i, lo, hi, phi, cx, cz, cons_in, fresh, g, dtk, dx, dz):
    """One PI consensus step (fig. 1, :class:`onboard.estimation.consensus.PIConsensus`) of
    agent ``i``'s quantities ``lo:hi`` with inputs ``phi`` and the fresh neighbours' payloads;
    ``dx``, ``dz`` are scratch."""
    for m in range(lo, hi):
        dx[m] = pi_input_rate(phi[m - lo], cx[i, m], g.cons_gamma)
        dz[m] = 0.0
    for j in range(fresh.shape[0]):
        if not fresh[j]:
            continue
        for m in range(lo, hi):
            a, b = pi_coupling_rates(
                cx[i, m], cz[i, m], cons_in[i, j, C_X + m], cons_in[i, j, C_Z + m],
                g.cons_kp, g.cons_ki,
            )  # fmt: skip
            dx[m] += a
            dz[m] += b
    for m in range(lo, hi):
        cx[i, m] += dtk * dx[m]
        cz[i, m] += dtk * dz[m]


@njit(cache=True)
def simulate(g, team, noise, state, trace):
    """Run the team for ``team.n_steps + 1`` steps; fills ``trace`` (every ``record_every``
    steps) and advances ``state`` in place. ``g`` holds the gains
    (:class:`sim.compiled_runner.Gains`). Returns the number of samples recorded."""
    mode, n_steps, dt = team.mode, team.n_steps, team.dt
    frame_every, delay, window_s = team.frame_every, team.delay, team.window_s
    adj, pair_ends, des, has_des, des_yaw = (
        team.adj, team.pair_ends, team.des, team.has_des, team.des_yaw
    )  # fmt: skip
    loss, seed = team.loss, team.seed
    p, yaw, yaw_offsets = state.p_ned, state.yaw_rad, state.yaw_offset_rad
    p_hat, yaw_hat, chi, u_cmd, rand_z = (
        state.p_hat_ned, state.yaw_hat_rad, state.chi_hat, state.u_cmd, state.rand_z
    )  # fmt: skip
    sigma_b, noise_v, noise_w = noise.sigma_bearing_rad, noise.sigma_v_m_s, noise.sigma_w_rad_s
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
    sfm_in = np.zeros((n, n, 2))  # stamp, chihat
    sfm_has = np.zeros((n, n), np.bool_)
    cons_in = np.zeros((n, n, C_LEN))
    cons_has = np.zeros((n, n), np.bool_)
    tab = np.full((n, n_pairs), -(1 << 40), np.int64)
    lam_hist = np.zeros((n_steps + 1, n_pairs))
    # ---- own data: bearings, frames, odometry, relative yaws
    beta_out = np.zeros((n, n, 3))
    bout_has = np.zeros((n, n), np.bool_)
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
    win_cap = int(window_s / dt) + 4  # the samples inside the window, and spare
    win_t = np.zeros((n_pairs, win_cap))
    win_v = np.zeros((n_pairs, win_cap))
    win_start = np.zeros(n_pairs, np.int64)
    win_count = np.zeros(n_pairs, np.int64)
    win_sum = np.zeros(n_pairs)
    # ---- consensus and control
    cx = np.zeros((n, N_Q))
    cz = np.zeros((n, N_Q))
    scratch_dx = np.zeros(N_Q)
    scratch_dz = np.zeros(N_Q)
    phi = np.zeros(3)
    fresh_c = np.zeros(n, np.bool_)
    c_init = np.zeros(n, np.bool_)
    lam_bar = np.zeros(n)
    e_index = np.zeros(n)
    k_e = np.zeros(n)
    w_l = np.zeros(n)
    sp = np.zeros((n, 4))  # setpoints: u (3), w
    rel = np.zeros((n, n, 3))
    rel_has = np.zeros((n, n), np.bool_)
    # ---- world
    v_body = np.zeros((n, 3))
    w_body = np.zeros(n)
    v_ned = np.zeros((n, 3))
    beta_now = np.zeros((n, n, 3))
    r_idx = 0
    frame_no = 0

    for k in range(n_steps + 1):
        t = k * dt
        dtk = t - (k - 1) * dt if k > 0 else 0.0  # the core's step: t_s - its previous t_s
        slot = k % ring
        src = (k - delay) % ring
        k_sent = k - delay
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
                    bb = ((c * r0 + s * r1) / d, (-s * r0 + c * r1) / d, r2 / d)
                    if sigma_b > 0.0:
                        zb = noise.bearing[frame_no, e]
                        bb = noisy_bearing(bb, (zb[0], zb[1], zb[2]), sigma_b)
                    beta_now[i, j, 0], beta_now[i, j, 1], beta_now[i, j, 2] = bb[0], bb[1], bb[2]
                    e += 1
            frame_no += 1

        # ---------------------------------------------------- 1. inbox: slot k - delay
        if k_sent >= 0:
            for i in range(n):
                for j in range(n):
                    if not comm[i, j]:
                        continue
                    if not (loss > 0.0 and lost(seed, k_sent, j, i, n, K_MOTION, loss)):
                        mot_in[i, j] = pub_mot[src, j]
                        mot_has[i, j] = True
                        kk = pair_of[i, j]
                        if kk >= 0 and pair_ends[kk, 0] == i:  # an observer's input
                            pm[kk, k_sent % hist] = pub_mot[src, j]
                            pm_step[kk, k_sent % hist] = k_sent
                            pm_newest[kk] = k_sent
                    if not (loss > 0.0 and lost(seed, k_sent, j, i, n, K_LOC, loss)):
                        loc_in[i, j] = pub_loc[src, j]
                        loc_has[i, j] = True
                    if not (loss > 0.0 and lost(seed, k_sent, j, i, n, K_CONS, loss)):
                        cons_in[i, j] = pub_cons[src, j]
                        cons_has[i, j] = True
                    if not (loss > 0.0 and lost(seed, k_sent, j, i, n, K_TAB, loss)):
                        for kk in range(n_pairs):
                            st = pub_tab[src, j, kk]
                            if st > tab[i, kk]:
                                tab[i, kk] = st
                    kk = pair_of[i, j]
                    if kk >= 0 and pair_ends[kk, 0] == j and pub_sfm_has[src, kk]:
                        if not (loss > 0.0 and lost(seed, k_sent, j, i, n, K_SFM, loss)):
                            sfm_in[i, j, 0] = k_sent * dt
                            sfm_in[i, j, 1] = pub_sfm[src, kk]
                            sfm_has[i, j] = True
                    if pub_bear_has[src, j] and not (
                        loss > 0.0 and lost(seed, k_sent, j, i, n, K_BEAR, loss)
                    ):
                        stamp = pub_bear[src, j, 0]
                        if adj[j, i] and (not bin_has[i, j] or stamp > bin_in[i, j, 0]):
                            bin_in[i, j, 0] = stamp
                            bin_in[i, j, 1:] = pub_beta[src, j, i]
                            bin_has[i, j] = True
                            # relative yaw: pair with the own frame of the same stamp
                            f = k_sent // frame_every % fring
                            if recip[i, j] and fr_step[i, f] == k_sent:
                                b_ij = (
                                    fr_beta[i, f, j, 0],
                                    fr_beta[i, f, j, 1],
                                    fr_beta[i, f, j, 2],
                                )
                                b_ji = (bin_in[i, j, 1], bin_in[i, j, 2], bin_in[i, j, 3])
                                if is_usable_pair(b_ij, b_ji, MIN_HORIZONTAL):
                                    off = yaw_offset(b_ij, b_ji, fr_yaw[i, f], pub_bear[src, j, 1])
                                    y_cos[i, j], y_sin[i, j], y_off[i, j] = filter_offset(
                                        y_cos[i, j], y_sin[i, j], not y_has[i, j], off, YAW_GAIN
                                    )
                                    y_has[i, j] = True

        # ---------------------------------------------------- per agent: AgentCore.step
        for i in range(n):
            # 2. own measurements (odometry yaw with its unknown offset)
            u0, u1, u2, w_i = v_body[i, 0], v_body[i, 1], v_body[i, 2], w_body[i]
            if noise_v > 0.0 or noise_w > 0.0:
                u0 += noise_v * noise.odometry[k, i, 0]
                u1 += noise_v * noise.odometry[k, i, 1]
                u2 += noise_v * noise.odometry[k, i, 2]
                w_i += noise_w * noise.odometry[k, i, 3]
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
                psi = relative_yaw_now(yaw_own, m[5] + m[4] * (t - m[0]), y_off[i, j])
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
            if tau1 * dt - tau0 * dt > tout:  # after a gap: restart, do not integrate
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
                ds = ts - (s_inst - 1) * dt  # the core's step between two instants
                mine = own_u[s_inst % hist, a]
                # the peer's motion at s: linear between received samples, held after the newest
                h1 = s_inst
                while pm_step[kk, h1 % hist] != h1 and h1 > s_inst - hist + 1:
                    h1 -= 1
                if pm_step[kk, h1 % hist] != h1:
                    continue
                m0 = pm[kk, h1 % hist]
                yaw_j, mj0, mj1, mj2 = m0[5], m0[1], m0[2], m0[3]
                gap_s = ts - h1 * dt
                if h1 < s_inst and h1 < pm_newest[kk]:
                    h2 = s_inst + 1
                    while pm_step[kk, h2 % hist] != h2:
                        h2 += 1
                    m1 = pm[kk, h2 % hist]
                    fa = interpolation_weight(ts, h1 * dt, h2 * dt)
                    mj0 = lerp(m0[1], m1[1], fa)
                    mj1 = lerp(m0[2], m1[2], fa)
                    mj2 = lerp(m0[3], m1[3], fa)
                    yaw_j = lerp_angle(m0[5], m1[5], fa)
                    gap_s = h2 * dt - h1 * dt
                if gap_s > team.max_odometry_gap_s:
                    # a hole in the peer's odometry: do not integrate across it, restart after it
                    b_has[kk] = False
                    applied[kk] = max(applied[kk], s_inst - s_inst % frame_every)
                    continue
                psi = relative_yaw_now(mine[4], yaw_j, y_off[a, b])
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
                exc[kk] = excitation(beta_p, u_ij)
                gate = excitation_gate(exc[kk], 0.0)
                bh_new, chi_new, q, xi_sq, _dchi, rate = observer_step(
                    beta_h, chi[kk], beta_p, u_ij, w_a, ds, g.alpha, g.h_other, g.h_floor, gate
                )
                e_folds[kk] += e_fold_increment(ds, gate, g.alpha, exc[kk])
                # E_ij (eq. 10): WindowAverage.add
                win_start[kk], win_count[kk], win_sum[kk], e_idx[kk] = window_add(
                    win_t[kk], win_v[kk], win_start[kk], win_count[kk], win_sum[kk],
                    ts, xi_sq, ds, window_s,
                )  # fmt: skip
                bp[kk, 0], bp[kk, 1], bp[kk, 2] = q[0], q[1], q[2]
                bh[kk, 0], bh[kk, 1], bh[kk, 2] = bh_new[0], bh_new[1], bh_new[2]
                chi[kk] = chi_new
                t_obs[kk] = ts
                chi_rate[kk] = rate
            pub_sfm[slot, kk] = chi[kk] + min(max(t - t_obs[kk], 0.0), tout) * chi_rate[kk]

        for i in range(n):
            u0, u1, u2 = own_u[k % hist, i, 0], own_u[k % hist, i, 1], own_u[k % hist, i, 2]
            w_i = own_u[k % hist, i, 3]
            # 6. localization filter (eq. 6): own bearings, neighbours' bearings, SfM distances,
            # summed in the core's order (out edges, in edges, distances; by neighbour id)
            pi_ = (p_hat[i, 0], p_hat[i, 1], p_hat[i, 2])
            gb = (0.0, 0.0, 0.0)
            g_yaw = 0.0
            for j in range(n):
                if adj[i, j] and loc_has[i, j] and bout_has[i, j] and t - loc_in[i, j, 0] <= tout:
                    lj = loc_in[i, j]
                    beta = (beta_out[i, j, 0], beta_out[i, j, 1], beta_out[i, j, 2])
                    gi, gy, _gj = bearing_term_gradient(
                        pi_, yaw_hat[i], (lj[1], lj[2], lj[3]), beta
                    )
                    gb = (gb[0] + gi[0], gb[1] + gi[1], gb[2] + gi[2])
                    g_yaw += gy
            for j in range(n):
                if adj[j, i] and loc_has[i, j] and bin_has[i, j] and t - loc_in[i, j, 0] <= tout:
                    lj = loc_in[i, j]
                    beta = (bin_in[i, j, 1], bin_in[i, j, 2], bin_in[i, j, 3])
                    _gi, _gy, gj = bearing_term_gradient((lj[1], lj[2], lj[3]), lj[4], pi_, beta)
                    gb = (gb[0] + gj[0], gb[1] + gj[1], gb[2] + gj[2])
            gd = (0.0, 0.0, 0.0)
            for j in range(n):
                if not (recip[i, j] and loc_has[i, j]):  # (a stale neighbour estimate too)
                    continue
                kk = pair_of[i, j]
                if pair_ends[kk, 0] == i:
                    c_ij = chi[kk] + min(max(t - t_obs[kk], 0.0), tout) * chi_rate[kk]
                    ok = True
                else:
                    c_ij = sfm_in[i, j, 1]
                    ok = sfm_has[i, j] and t - sfm_in[i, j, 0] <= tout
                if ok and c_ij >= g.chi_min:
                    lj = loc_in[i, j]
                    dg = distance_term_gradient(pi_, (lj[1], lj[2], lj[3]), 1.0 / c_ij)
                    gd = (gd[0] + dg[0], gd[1] + dg[1], gd[2] + dg[2])
            p_new, yaw_hat[i] = localization_euler_step(
                pi_, yaw_hat[i], dtk, (u0, u1, u2), w_i, gb, g_yaw, gd,
                g.k_loc_b, g.k_loc_d, g.loc_max_m_s, g.loc_max_rad_s,
            )  # fmt: skip
            p_hat[i, 0], p_hat[i, 1], p_hat[i, 2] = p_new[0], p_new[1], p_new[2]

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
                    acc += lambda_bar_term(lam_hist[st, kk], g.p_norm)
                    any_fresh = True
                    if k % team.relay_every == 0 or pair_ends[kk, 0] == i:
                        pub_tab[slot, i, kk] = st
            lam_bar[i] = lambda_bar_of_sum(acc, g.p_norm) if any_fresh else 0.0
            # PI average consensus (fig. 1) of E; in case 4 also of pbar and dlambdabar/dw_l
            e_sum = 0.0
            for kk in range(n_pairs):
                if pair_ends[kk, 0] == i:
                    e_sum += e_idx[kk] + (g.e_high if e_folds[kk] < g.e_folds_min else 0.0)
            # d lambdabar / d u_i (eq. 12) from the own bearings and relative velocities
            gr = (0.0, 0.0, 0.0)
            for j in range(n):
                if rel_has[i, j] and bout_has[i, j]:
                    beta = (beta_out[i, j, 0], beta_out[i, j, 1], beta_out[i, j, 2])
                    u_ij = (rel[i, j, 0], rel[i, j, 1], rel[i, j, 2])
                    gr = lambda_bar_gradient_term(
                        gr, beta, u_ij, excitation(beta, u_ij), lam_bar[i], g.p_norm
                    )
            case4 = mode == 3
            for j in range(n):
                fresh_c[j] = comm[i, j] and cons_has[i, j] and t - cons_in[i, j, C_STAMP] <= tout
            if not c_init[i]:  # PIConsensus starts at its first input
                cx[i, Q_E], cz[i, Q_E] = e_sum, 0.0
                for m3 in range(3):
                    cx[i, Q_P + m3], cz[i, Q_P + m3] = p_hat[i, m3], 0.0
            phi[0] = e_sum
            consensus_step(i, Q_E, Q_E + 1, phi, cx, cz, cons_in, fresh_c, g, dtk,
                           scratch_dx, scratch_dz)  # fmt: skip
            e_index[i] = max(n * cx[i, Q_E], 0.0)
            n3 = (0.0, 0.0, 0.0)
            if case4:
                consensus_step(i, Q_P, Q_P + 3, p_hat[i], cx, cz, cons_in, fresh_c, g, dtk,
                               scratch_dx, scratch_dz)  # fmt: skip
                n3 = rotation_velocity_body(
                    (p_hat[i, 0], p_hat[i, 1], p_hat[i, 2]),
                    yaw_hat[i],
                    (cx[i, Q_P], cx[i, Q_P + 1], cx[i, Q_P + 2]),
                )
                phi[0] = gr[0] * n3[0] + gr[1] * n3[1] + gr[2] * n3[2]
                if not c_init[i]:
                    cx[i, Q_D], cz[i, Q_D] = phi[0], 0.0
                consensus_step(i, Q_D, Q_D + 1, phi, cx, cz, cons_in, fresh_c, g, dtk,
                               scratch_dx, scratch_dz)  # fmt: skip
            c_init[i] = True

            # 8. control
            if mode == 0:  # active perception, eq. 12
                uc = (u_cmd[i, 0], u_cmd[i, 1], u_cmd[i, 2])
                du = active_velocity_rate(uc, gr, g.k_nu, g.nu_star, g.k_lambda)
                for m3 in range(3):
                    u_cmd[i, m3] += dtk * du[m3]
                v0, v1, v2, w_c = u_cmd[i, 0], u_cmd[i, 1], u_cmd[i, 2], 0.0
            elif mode == 1:  # random directions at the same speed (Ornstein-Uhlenbeck)
                zr = (rand_z[i, 0], rand_z[i, 1], rand_z[i, 2])
                if dtk > 0.0:
                    rn = noise.random_motion[i, k - 1]
                    zr = ou_direction_step(zr, (rn[0], rn[1], rn[2]), dtk, g.random_tau_s)
                    rand_z[i, 0], rand_z[i, 1], rand_z[i, 2] = zr[0], zr[1], zr[2]
                v0, v1, v2 = ou_velocity(zr, team.speed)
                w_c = 0.0
            elif mode == 4:  # hold
                v0, v1, v2, w_c = 0.0, 0.0, 0.0, 0.0
            else:  # bearing formation (paper 002 eq. 20) and yaw alignment
                a3 = (0.0, 0.0, 0.0)
                for j in range(n):
                    if adj[i, j] and bout_has[i, j] and has_des[i, j]:
                        beta = (beta_out[i, j, 0], beta_out[i, j, 1], beta_out[i, j, 2])
                        a3 = formation_out_term(
                            a3, beta, (des[i, j, 0], des[i, j, 1], des[i, j, 2])
                        )
                yaw_sum = 0.0
                for j in range(n):
                    if not (comm[i, j] and loc_has[i, j] and t - loc_in[i, j, 0] <= tout):
                        continue
                    yaw_j = loc_in[i, j, 4]
                    if team.use_des_yaw:
                        yaw_sum += yaw_alignment_term(yaw_hat[i], yaw_j, des_yaw[j] - des_yaw[i])
                    if bin_has[i, j] and has_des[j, i]:
                        beta = (bin_in[i, j, 1], bin_in[i, j, 2], bin_in[i, j, 3])
                        a3 = formation_in_term(
                            a3, yaw_j - yaw_hat[i], beta, (des[j, i, 0], des[j, i, 1], des[j, i, 2])
                        )
                v0, v1, v2 = g.k_formation * a3[0], g.k_formation * a3[1], g.k_formation * a3[2]
                w_c = g.k_yaw * yaw_sum
                if case4:  # bearing-constrained active perception, eq. 13-16
                    k_e[i] = convergence_gain(e_index[i], g.e_low, g.e_high)
                    dw = rotation_rate_derivative(
                        w_l[i],
                        n * cx[i, Q_D],
                        lam_bar[i],
                        k_e[i],
                        g.k_w,
                        g.k_lambda0,
                        g.gamma,
                        g.w_l_start,
                    )
                    shared = 0.0
                    for j in range(n):
                        if fresh_c[j]:
                            shared += cons_in[i, j, C_WL] - w_l[i]
                    dw += g.k_wl_coupling * shared
                    w_l[i] = max(-g.w_l_max, min(g.w_l_max, w_l[i] + dtk * dw))
                    v0, v1, v2 = v0 + w_l[i] * n3[0], v1 + w_l[i] * n3[1], v2 + w_l[i] * n3[2]
                    w_c += w_l[i]
            v0, v1, v2 = saturate(v0, v1, v2, g.v_max)
            sp[i, 0], sp[i, 1], sp[i, 2] = v0, v1, v2
            sp[i, 3] = max(-g.w_max, min(g.w_max, w_c))

            # 9. publish: consensus, motion, localization
            pc = pub_cons[slot, i]
            pc[C_STAMP] = t
            pc[C_X : C_X + N_Q] = cx[i]
            pc[C_Z : C_Z + N_Q] = cz[i]
            pc[C_WL] = w_l[i]
            pub_mot[slot, i, 0] = t
            pub_mot[slot, i, 1:5] = own_u[k % hist, i, 0:4]
            pub_mot[slot, i, 5] = own_u[k % hist, i, 4]
            pub_loc[slot, i, 0] = t
            pub_loc[slot, i, 1:4] = p_hat[i]
            pub_loc[slot, i, 4] = yaw_hat[i]

        # ---------------------------------------------------- record (truth and estimates)
        if k % team.record_every == 0:
            trace.t_s[r_idx] = t
            for i in range(n):
                c, s = math.cos(yaw[i]), math.sin(yaw[i])
                trace.p_ned[r_idx, i] = p[i]
                trace.yaw_rad[r_idx, i] = yaw[i]
                trace.v_ned[r_idx, i, 0] = c * v_body[i, 0] - s * v_body[i, 1]
                trace.v_ned[r_idx, i, 1] = s * v_body[i, 0] + c * v_body[i, 1]
                trace.v_ned[r_idx, i, 2] = v_body[i, 2]
                trace.p_hat_ned[r_idx, i] = p_hat[i]
                trace.yaw_hat_rad[r_idx, i] = yaw_hat[i]
                trace.lambda_bar[r_idx, i] = lam_bar[i]
                trace.e_index[r_idx, i] = e_index[i]
                trace.k_e[r_idx, i] = k_e[i]
                trace.w_l[r_idx, i] = w_l[i]
            for kk in range(n_pairs):
                trace.chi_hat[r_idx, kk] = (
                    chi[kk] + min(max(t - t_obs[kk], 0.0), tout) * chi_rate[kk]
                )
            r_idx += 1

        # ---------------------------------------------------- world (paper 000 eq. 1, Euler)
        for i in range(n):
            pi_new, yaw[i], vn, vb, w_body[i] = kinematic_step(
                (p[i, 0], p[i, 1], p[i, 2]), yaw[i], (v_ned[i, 0], v_ned[i, 1], v_ned[i, 2]),
                w_body[i], (sp[i, 0], sp[i, 1], sp[i, 2]), sp[i, 3], dt, team.lag_v, team.lag_w,
            )  # fmt: skip
            p[i, 0], p[i, 1], p[i, 2] = pi_new[0], pi_new[1], pi_new[2]
            v_ned[i, 0], v_ned[i, 1], v_ned[i, 2] = vn[0], vn[1], vn[2]
            v_body[i, 0], v_body[i, 1], v_body[i, 2] = vb[0], vb[1], vb[2]
    return r_idx

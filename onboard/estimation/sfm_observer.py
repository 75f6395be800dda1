"""Inverse-depth structure-from-motion observer on one reciprocal edge (paper 000, Sect. III-C).

With ``chi_ij = 1/d_ij`` the body-frame bearing evolves as (eq. 7)

    beta_dot = -w_i S beta + P u_ij chi,        chi_dot = -chi^2 u_ij^T beta,

where ``u_ij = iR_j u_j - u_i`` is the relative velocity in ``i``'s body frame. The observer
(eq. 8), with ``Omega = u_ij^T P`` (1x3) and ``xi = betahat - beta``, is

    betahat_dot = -w_i S beta + Omega^T chihat - H xi,
    chihat_dot  = -chihat^2 u_ij^T beta - alpha Omega xi.

Gain shaping (paper 000 Sect. V, from Spica & Robuffo Giordano's active SfM): with the SVD
``Omega = U Sigma V^T``, ``H = V C V^T`` and ``C = diag(2 sqrt(alpha lambda), h, h)``. For a 1x3
``Omega`` the first right singular vector is ``v1 = P u / |P u|`` and ``sigma^2 = lambda =
u^T P u``, so ``H = h I + (c1 - h) v1 v1^T`` in closed form (no SVD is computed): the
``(xi along v1, chi error)`` pair becomes a critically damped second-order system
``s^2 + c1 s + alpha lambda``. ``c1`` is floored at ``h_floor`` so ``H`` stays positive
definite when the edge is not excited (``v1`` is then undefined and ``H = h I``).

The observer converges iff the excitation ``lambda(t)`` is persistent (eq. 9). Its measurable
convergence index is ``E_ij = (1/T) int_{t-T}^t |xi|^2`` (eq. 10, :class:`WindowAverage`).

Implementation notes: the math is plain float arithmetic on 3-tuples because one agent runs a
handful of edges every 2 ms and numpy's per-call overhead would dominate. Integration is
explicit Euler with the agent's step (2 ms in the paper; the fastest observer mode is
``h = 10 1/s``, so ``h dt = 0.02``). The camera delivers bearings at 50 Hz while the observer
runs at the control rate: between frames the measured bearing is *predicted* with the model
(eq. 7) using the current ``chihat`` (:func:`predict_bearing`), which also compensates the
capture latency; at convergence the prediction is exact, so it adds no bias.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

Vec3 = tuple[float, float, float]

ALPHA = 10.0
"""Observer gain ``alpha`` (paper 000 Sect. V)."""
H_OTHER = 10.0
"""Gain ``C_22 = C_33`` on the bearing error normal to ``P u``."""
H_FLOOR = 1e-3
"""Lower bound of ``c1 = 2 sqrt(alpha lambda)`` so that ``H`` stays positive definite."""


def excitation(beta: Vec3, u_ij: Vec3) -> float:
    """``lambda_ij = Omega Omega^T = u_ij^T P_ij u_ij = |u|^2 - (beta . u)^2`` (Sect. III-C)."""
    bu = beta[0] * u_ij[0] + beta[1] * u_ij[1] + beta[2] * u_ij[2]
    return max(u_ij[0] * u_ij[0] + u_ij[1] * u_ij[1] + u_ij[2] * u_ij[2] - bu * bu, 0.0)


def bearing_rate(beta: Vec3, chi: float, u_ij: Vec3, w_i: float) -> Vec3:
    """Model (eq. 7): ``beta_dot = -w_i S beta + P u_ij chi`` with ``S = hat(e3)``."""
    bu = beta[0] * u_ij[0] + beta[1] * u_ij[1] + beta[2] * u_ij[2]
    return (
        w_i * beta[1] + (u_ij[0] - beta[0] * bu) * chi,
        -w_i * beta[0] + (u_ij[1] - beta[1] * bu) * chi,
        (u_ij[2] - beta[2] * bu) * chi,
    )


def predict_bearing(beta: Vec3, chi: float, u_ij: Vec3, w_i: float, dt: float) -> Vec3:
    """One Euler step of eq. 7 followed by renormalization onto the unit sphere. A step that
    lands on the origin (or overflows) has no direction: the bearing is kept (issue 23)."""
    d = bearing_rate(beta, chi, u_ij, w_i)
    x, y, z = beta[0] + dt * d[0], beta[1] + dt * d[1], beta[2] + dt * d[2]
    n = math.sqrt(x * x + y * y + z * z)
    if not (n > 0.0 and math.isfinite(n)):
        return beta
    return (x / n, y / n, z / n)


def excitation_gate(lam: float, bias_speed_m_s: float) -> float:
    """Weight ``g`` in ``[0, 1]`` of the observer's correction for an odometry whose velocity is
    off by up to ``bias_speed_m_s`` (not in the paper; 0: always 1, paper 000's observer).

    The correction ``-alpha Omega xi`` attributes the bearing's unexplained motion to the
    inverse depth. With a velocity bias ``delta`` the steady-state relative error of
    ``chihat`` is about ``|P delta| / |P u|``: when the measured excitation ``|P u| =
    sqrt(lambda)`` is no larger than the bias (a hovering team whose formation control flies
    against the bias: ``u`` is then mostly the bias), it is all error and ``chihat`` walks
    away. ``g = 0`` below ``|P u| = b``, rising linearly to 1 at ``2 b``."""
    if bias_speed_m_s <= 0.0:
        return 1.0
    return min(max(math.sqrt(lam) / bias_speed_m_s - 1.0, 0.0), 1.0)


def observer_rates(
    beta_hat: Vec3,
    chi_hat: float,
    beta: Vec3,
    u_ij: Vec3,
    w_i: float,
    alpha: float = ALPHA,
    h_other: float = H_OTHER,
    h_floor: float = H_FLOOR,
    gate: float = 1.0,
) -> tuple[Vec3, float]:
    """Right-hand side of the observer (eq. 8) with the SVD-shaped gain ``H``.

    ``gate`` (:func:`excitation_gate`) scales the inverse-depth correction, ``alpha_eff = g
    alpha``; ``c1`` keeps the pair critically damped for ``alpha_eff`` and, as ``g`` falls,
    blends towards ``h_other`` so the bearing error along ``P u`` stays damped while ``chihat``
    is not corrected (it would otherwise pile up and kick ``chihat`` when the motion resumes).
    ``gate = 1`` is eq. 8 exactly. Returns ``(betahat_dot, chihat_dot)``.
    """
    alpha_eff = gate * alpha
    bu = beta[0] * u_ij[0] + beta[1] * u_ij[1] + beta[2] * u_ij[2]
    o0, o1, o2 = u_ij[0] - beta[0] * bu, u_ij[1] - beta[1] * bu, u_ij[2] - beta[2] * bu  # Omega^T
    x0, x1, x2 = beta_hat[0] - beta[0], beta_hat[1] - beta[1], beta_hat[2] - beta[2]  # xi
    lam = o0 * o0 + o1 * o1 + o2 * o2
    o_xi = o0 * x0 + o1 * x1 + o2 * x2  # Omega xi
    if lam > 1e-12:
        c1 = max(2.0 * math.sqrt(alpha_eff * lam) + (1.0 - gate) * h_other, h_floor)
        k = (c1 - h_other) * o_xi / lam  # H xi = h xi + (c1 - h) v1 (v1 . xi)
        h0, h1, h2 = h_other * x0 + k * o0, h_other * x1 + k * o1, h_other * x2 + k * o2
    else:
        h0, h1, h2 = h_other * x0, h_other * x1, h_other * x2
    d_beta_hat = (
        w_i * beta[1] + o0 * chi_hat - h0,
        -w_i * beta[0] + o1 * chi_hat - h1,
        o2 * chi_hat - h2,
    )
    d_chi_hat = -chi_hat * chi_hat * bu - alpha_eff * o_xi
    return d_beta_hat, d_chi_hat


def observer_step(
    beta_hat: Vec3,
    chi_hat: float,
    beta: Vec3,
    u_ij: Vec3,
    w_i: float,
    dt: float,
    alpha: float = ALPHA,
    h_other: float = H_OTHER,
    h_floor: float = H_FLOOR,
    gate: float = 1.0,
) -> tuple[Vec3, float, Vec3, float, float, float]:
    """One explicit-Euler step of the observer (eq. 8) and of the predicted bearing (eq. 7).

    ``beta`` is the measured bearing predicted to the step's start. Returns ``(betahat,
    chihat, beta)`` after the step, ``|xi|^2`` at its start (the integrand of eq. 10),
    ``chihat'`` (:func:`observer_rates`) and the model rate ``-chihat^2 u_ij^T beta`` after it
    (to carry ``chihat`` forward, :meth:`SfmEdge.chi_at`)."""
    d_bh, d_chi = observer_rates(beta_hat, chi_hat, beta, u_ij, w_i, alpha, h_other, h_floor, gate)
    x0, x1, x2 = beta_hat[0] - beta[0], beta_hat[1] - beta[1], beta_hat[2] - beta[2]
    xi_sq = x0 * x0 + x1 * x1 + x2 * x2
    beta_new = predict_bearing(beta, chi_hat, u_ij, w_i, dt)
    beta_hat_new = (
        beta_hat[0] + dt * d_bh[0],
        beta_hat[1] + dt * d_bh[1],
        beta_hat[2] + dt * d_bh[2],
    )
    chi_new = chi_hat + dt * d_chi
    ub = u_ij[0] * beta_new[0] + u_ij[1] * beta_new[1] + u_ij[2] * beta_new[2]
    return beta_hat_new, chi_new, beta_new, xi_sq, d_chi, -chi_new * chi_new * ub


def bias_rate(
    beta_hat: Vec3,
    beta: Vec3,
    u_ij: Vec3,
    chi_hat: float,
    gate: float,
    bias_gain: float,
) -> Vec3:
    """Correction of the relative velocity bias estimate ``deltahat`` (docs/equations.md,
    "Relative velocity bias of an SfM edge"; not in the paper):

        deltahat_dot = -(gamma / chihat) (P xi - g v1 v1^T xi),   v1 = P u / |P u|,

    with ``u`` the bias-corrected relative velocity ``u_ij + deltahat`` and ``g`` the excitation
    gate. ``P xi`` is the bearing motion the model does not explain; along ``v1`` the inverse
    depth explains it as well, so that part is learned only as far as the gate keeps ``chihat``
    from being corrected (``g = 0``: a still team, all of it is bias). ``1/chihat`` makes the
    ``(xi, delta)`` pair ``s^2 + h s + gamma`` at any distance."""
    x0, x1, x2 = beta_hat[0] - beta[0], beta_hat[1] - beta[1], beta_hat[2] - beta[2]
    bx = beta[0] * x0 + beta[1] * x1 + beta[2] * x2
    p0, p1, p2 = x0 - beta[0] * bx, x1 - beta[1] * bx, x2 - beta[2] * bx  # P xi
    bu = beta[0] * u_ij[0] + beta[1] * u_ij[1] + beta[2] * u_ij[2]
    o0, o1, o2 = u_ij[0] - beta[0] * bu, u_ij[1] - beta[1] * bu, u_ij[2] - beta[2] * bu  # P u
    lam = o0 * o0 + o1 * o1 + o2 * o2
    if lam > 1e-12 and gate > 0.0:
        k = gate * (o0 * p0 + o1 * p1 + o2 * p2) / lam
        p0, p1, p2 = p0 - k * o0, p1 - k * o1, p2 - k * o2
    c = -bias_gain / max(chi_hat, 1e-6)
    return (c * p0, c * p1, c * p2)


def bias_update(delta_hat: Vec3, d_delta: Vec3, dt: float, bias_max_m_s: float) -> Vec3:
    """One Euler step of :func:`bias_rate`, the estimate kept within ``|deltahat| <=
    bias_max_m_s`` (docs/equations.md, "Relative velocity bias of an SfM edge"): an odometry
    bias is a few cm/s, and a larger estimate is the inverse depth's error leaking into it."""
    x = delta_hat[0] + dt * d_delta[0]
    y = delta_hat[1] + dt * d_delta[1]
    z = delta_hat[2] + dt * d_delta[2]
    n = math.sqrt(x * x + y * y + z * z)
    if not math.isfinite(n):
        return delta_hat
    if n > bias_max_m_s:
        s = bias_max_m_s / n
        return (x * s, y * s, z * s)
    return (x, y, z)


def e_fold_increment(dt: float, gate: float, alpha: float, lam: float) -> float:
    """``dt sqrt(g alpha lambda)``: the e-foldings one step gives the critically damped error
    pair of the SVD-shaped observer (:attr:`SfmEdge.e_folds`)."""
    return dt * math.sqrt(gate * alpha * lam)


def window_add(
    times: list[float],
    values: list[float],
    start: int,
    count: int,
    integral: float,
    t_s: float,
    value: float,
    dt: float,
    window_s: float,
) -> tuple[int, int, float, float]:
    """Add ``value`` held over ``(t_s - dt, t_s]`` to the window integral of eq. 10.

    The samples live in a ring buffer ``times``/``values`` (lists or arrays of one capacity,
    written in place) from index ``start``, ``count`` of them; samples at or before ``t_s -
    window_s`` leave it. A full buffer forgets its oldest sample first (size it for the
    window). Returns ``(start, count, integral, average)`` with ``average = max(integral, 0)
    / window_s``, exact for piecewise constant samples and any step sizes."""
    cap = len(times)
    if count == cap:
        integral -= values[start]
        start = (start + 1) % cap
        count -= 1
    idx = (start + count) % cap
    times[idx] = t_s
    values[idx] = value * dt
    count += 1
    integral += value * dt
    horizon = t_s - window_s
    while count > 0 and times[start] <= horizon:
        integral -= values[start]
        start = (start + 1) % cap
        count -= 1
    return start, count, integral, max(integral, 0.0) / window_s


@dataclass(slots=True)
class WindowAverage:
    """``(1/T) int_{t-T}^{t} y(tau) dtau`` of a sampled signal (eq. 10, :func:`window_add`),
    exact for piecewise constant samples, with any step sizes. O(1) amortized per sample."""

    window_s: float = 1.0
    _times: list[float] = field(default_factory=lambda: [0.0] * 64)
    _values: list[float] = field(default_factory=lambda: [0.0] * 64)
    _start: int = 0
    _count: int = 0
    _integral: float = 0.0

    def add(self, t_s: float, value: float, dt: float) -> float:
        """Add ``value`` held over ``(t_s - dt, t_s]`` and return the current window average."""
        if self._count == len(self._times):  # full: the window holds more samples, grow
            order = [(self._start + m) % self._count for m in range(self._count)]
            self._times = [self._times[m] for m in order] + [0.0] * self._count
            self._values = [self._values[m] for m in order] + [0.0] * self._count
            self._start = 0
        self._start, self._count, self._integral, avg = window_add(
            self._times, self._values, self._start, self._count, self._integral,
            t_s, value, dt, self.window_s,
        )  # fmt: skip
        return avg

    @property
    def value(self) -> float:
        return max(self._integral, 0.0) / self.window_s


@dataclass(slots=True)
class SfmEdge:
    """Observer (eq. 8) of one reciprocal edge ``(i, j)``, run by agent ``i`` (the lower id).

    Feed camera frames with :meth:`new_bearing` and advance with :meth:`step` every control
    period. ``chi_hat`` is the inverse-distance estimate (1/m), ``e_index`` is ``E_ij``.
    """

    chi_hat: float
    alpha: float = ALPHA
    h_other: float = H_OTHER
    h_floor: float = H_FLOOR
    window: WindowAverage = field(default_factory=WindowAverage)
    beta_hat: Vec3 | None = None
    beta_pred: Vec3 | None = None
    excitation: float = 0.0
    e_index: float = 0.0
    last_frame_s: float = -math.inf
    e_folds: float = 0.0
    """``int sqrt(alpha lambda) dt``: with the SVD-shaped gain the (bearing, inverse depth) error
    pair is the critically damped ``s^2 + c1 s + alpha lambda`` (module docstring), so the
    estimation error decays like ``exp(-int sqrt(alpha lambda) dt)``: this counts the e-foldings
    the initial error has had (5: under 1% left)."""
    t_s: float = -math.inf
    """Time the observer has been advanced to (the agent runs it up to its newest frame)."""
    chi_rate: float = 0.0
    """Model rate ``-chihat^2 u_ij^T beta`` (eq. 7) at ``t_s``, for :meth:`chi_at`."""
    bias_speed_m_s: float = 0.0
    """Odometry velocity error level of :func:`excitation_gate` (0: paper 000's observer)."""
    folds_forget_s: float = 0.0
    """Time constant over which :attr:`e_folds` is forgotten (0: never, paper 000): excitation
    long ago does not vouch for an estimate an odometry bias has had time to move since."""
    wander_window: WindowAverage | None = None
    """Window of the correction-driven relative change ``-alpha_eff Omega xi / chihat``, its
    increases (and :attr:`_wander_down` its decreases; None: not watched)."""
    wander_max: float = 0.0
    """Largest relative change of ``chihat`` by corrections within :attr:`wander_window`
    compatible with convergence; above it :attr:`e_folds` is held below ``folds_cap``."""
    folds_cap: float = math.inf
    gate: float = 1.0
    """Excitation gate of the last step."""
    wander: float = 0.0
    """Net correction-driven relative change of ``chihat`` over the last wander window (white
    odometry noise averages out of it; a bias the observer keeps fighting does not)."""
    _wander_down: WindowAverage | None = None
    bias_gain: float = 0.0
    """Gain ``gamma`` (1/s^2) of the relative velocity bias estimate (:func:`bias_rate`; 0: not
    estimated, paper 000's observer). Not in the paper."""
    bias_max_m_s: float = 0.1
    """Largest bias estimate (:func:`bias_update`)."""
    delta_hat: Vec3 = (0.0, 0.0, 0.0)
    """Estimate of the relative velocity odometry error ``delta = u_true - u_ij`` (m/s, ``i``'s
    body frame); the observer runs on ``u_ij + deltahat``."""

    def corrected(self, u_ij: Vec3) -> Vec3:
        """``u_ij + deltahat``: the relative velocity with the estimated bias removed."""
        d = self.delta_hat
        return (u_ij[0] + d[0], u_ij[1] + d[1], u_ij[2] + d[2])

    def new_bearing(self, beta: Vec3, stamp_s: float, t_s: float, u_ij: Vec3, w_i: float) -> None:
        """Take a camera frame captured at ``stamp_s`` and predict it forward to ``t_s``."""
        if stamp_s <= self.last_frame_s:
            return
        self.last_frame_s = stamp_s
        if self.bias_gain > 0.0:
            u_ij = self.corrected(u_ij)
        self.beta_pred = predict_bearing(beta, self.chi_hat, u_ij, w_i, t_s - stamp_s)
        if self.beta_hat is None:
            self.beta_hat = self.beta_pred

    def chi_at(self, t_s: float, horizon_s: float) -> float:
        """``chihat`` carried from the observer's time to ``t_s`` with the model (eq. 7).

        The agent advances the observer only up to the capture time of its newest frame, so
        ``chihat`` is the inverse distance of that instant: with camera frames at 10 Hz and their
        latency, 0.1-0.2 s ago, long enough for a moving team's distances to change by 1-2%.
        Users of the estimate want it now; the prediction covers at most ``horizon_s``."""
        dt = min(max(t_s - self.t_s, 0.0), horizon_s)
        return self.chi_hat + dt * self.chi_rate

    def resync(self) -> None:
        """Forget the bearing state after a hole in the inputs; the next frame restarts it.

        ``betahat`` is an estimate of a *measured* quantity: across a hole it was not integrated
        while the true bearing moved on, and the first frame after it would show up as a large
        error ``xi`` that eq. 8 turns into a kick of ``chihat`` (``-alpha Omega xi``). Setting
        ``betahat`` to the next measurement loses nothing; ``chihat`` is kept."""
        self.beta_hat = None
        self.beta_pred = None

    def step(self, t_s: float, dt: float, u_ij: Vec3, w_i: float) -> None:
        """Advance the observer by ``dt`` with relative velocity ``u_ij`` and own yaw rate."""
        beta, beta_hat = self.beta_pred, self.beta_hat
        if beta is None or beta_hat is None or dt <= 0.0:
            return
        if self.bias_gain > 0.0:
            u_ij = self.corrected(u_ij)
        self.excitation = excitation(beta, u_ij)
        self.gate = gate = excitation_gate(self.excitation, self.bias_speed_m_s)
        if self.bias_gain > 0.0:
            d_delta = bias_rate(beta_hat, beta, u_ij, self.chi_hat, gate, self.bias_gain)
        beta_hat_new, chi_new, beta_new, xi_sq, d_chi, chi_rate = observer_step(
            beta_hat, self.chi_hat, beta, u_ij, w_i, dt,
            self.alpha, self.h_other, self.h_floor, gate,
        )  # fmt: skip
        self.e_folds += e_fold_increment(dt, gate, self.alpha, self.excitation)
        if self.folds_forget_s > 0.0:
            self.e_folds *= math.exp(-dt / self.folds_forget_s)
        if self.wander_window is not None and self.chi_hat > 0.0:
            bu = beta[0] * u_ij[0] + beta[1] * u_ij[1] + beta[2] * u_ij[2]
            corr = (d_chi + self.chi_hat * self.chi_hat * bu) / self.chi_hat
            up, down = self.wander_window, self._wander_down
            if down is None:
                down = self._wander_down = WindowAverage(up.window_s)
            net = up.add(t_s, max(corr, 0.0), dt) - down.add(t_s, max(-corr, 0.0), dt)
            self.wander = abs(net) * up.window_s
            if self.wander > self.wander_max:
                self.e_folds = min(self.e_folds, self.folds_cap)
        self.e_index = self.window.add(t_s, xi_sq, dt)
        self.beta_pred = beta_new
        self.beta_hat = beta_hat_new
        self.chi_hat = chi_new
        if self.bias_gain > 0.0:
            self.delta_hat = bias_update(self.delta_hat, d_delta, dt, self.bias_max_m_s)
        self.t_s = t_s
        self.chi_rate = chi_rate

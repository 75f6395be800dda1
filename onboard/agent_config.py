"""The agent core's configuration: everything one agent needs, with paper 000's values as defaults.

Its own module so that the layers the core composes (:mod:`onboard.rigidity_layer`) can take it
without importing the core itself.
"""

from __future__ import annotations

from typing import Literal

import msgspec

Vec3 = tuple[float, float, float]
Mode = Literal["active", "random", "formation", "formation-active", "hold", "rigidity-tracking"]


class AgentConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Everything one agent core needs, with paper 000's values as defaults."""

    agent_id: int
    n_agents: int
    edges: tuple[tuple[int, int], ...]
    """Directed sensing graph of the fleet: ``(i, j)`` means ``i`` measures the bearing to ``j``.
    Agents communicate along every edge in both directions."""
    mode: Mode = "active"
    p_hat0_ned: tuple[Vec3, ...] = ()
    """Initial localization guess of every agent (the shared prior of paper 000 Sect. V; it also
    initializes the SfM observers, ``chihat_ij = 1 / |phat_j - phat_i|``)."""
    yaw_hat0_rad: tuple[float, ...] = ()
    desired_beta_body: tuple[tuple[int, int, Vec3], ...] = ()
    """Desired formation: body-frame bearing ``beta*_ij`` per edge ``(i, j, beta)``."""
    desired_yaw_rad: tuple[float, ...] = ()
    """Desired yaws (only their differences matter)."""
    seed: int = 0

    # SfM observer (eq. 8) and convergence index (eq. 10)
    alpha: float = 10.0
    h_other: float = 10.0
    h_floor: float = 1e-3
    e_window_s: float = 1.0
    sfm_bias_speed_m_s: float = 0.1
    """Odometry velocity error the SfM observers tolerate (:func:`~onboard.estimation.\
sfm_observer.excitation_gate`): they correct their inverse depth only where the relative
    velocity normal to the bearing exceeds it (fully above twice it). Real autopilots' velocity
    is off by 1-5 cm/s (ArduCopter SITL, docs/sim.md), and a hovering team whose formation
    control flies against that bias let the observers walk away (issue 22). 0: paper 000's
    observer (the paper reproductions, ``sim/scenarios.py``). Not in the paper."""
    sfm_folds_forget_s: float = 0.0
    """The e-foldings of excitation (:attr:`SfmEdge.e_folds`) are forgotten over this time
    (0: never, paper 000): without recent excitation the scale is no longer claimed converged,
    and the active motion (gate of eq. 16, :attr:`converged_e_folds`) resumes. Not in the
    paper."""
    sfm_wander_window_s: float = 2.0
    sfm_wander_max: float = 0.02
    """While an observer's corrections moved its ``chihat`` by more than this fraction within
    the last ``sfm_wander_window_s`` its e-foldings are held below :attr:`converged_e_folds`:
    an estimate that wanders is not converged (0: not watched, paper 000). Not in the paper."""
    chi_min_inv_m: float = 0.02
    """SfM estimates below this (distance above 50 m) are not used as virtual measurements."""
    # localization (eq. 6)
    k_loc_bearing: float = 100.0
    k_loc_distance: float = 1.0
    # consensus (PI estimator) and the sharing of w_l between neighbours. Peer values arrive one
    # network delay ``tau`` late, and a delayed consensus ``x' = -k L x(t - tau)`` is stable only
    # while ``k mu_max tau < pi/2`` (Olfati-Saber & Murray 2004; ``mu_max`` the largest Laplacian
    # eigenvalue, 6-8 in the demo graphs). ``k_p = 20`` failed at 60 ms; ``k_p = k_i = 1`` holds
    # past 200 ms with 10% loss, at the price of a slower case 4 (6.5 s -> 7-9 s to converge).
    consensus_gamma: float = 50.0
    consensus_k_p: float = 1.0
    consensus_k_i: float = 1.0
    k_w_l_coupling: float = 2.0
    w_l_max_rad_s: float = 0.3
    """Bound of the active rotation rate ``w_l`` of eq. 13-15 (anti-windup, not in the paper)."""
    excitation_relay_every: int = 5
    """Steps between relays of the whole excitation table (own edges go out every step)."""
    # unconstrained active perception (eq. 11-12)
    p_norm: float = -5.0
    k_nu: float = 10.0
    nu_star: float = 0.25
    k_lambda: float = 15.0
    # bearing-constrained active perception (eq. 13-16)
    k_w: float = 1.0
    gamma: float = 0.05
    k_lambda0: float = 2.0
    e_low: float = 1e-4
    e_high: float = 1e-3
    converged_e_folds: float = 5.0
    """An SfM edge counts as excited once ``int sqrt(alpha lambda) dt`` (the e-foldings of its
    error, :attr:`SfmEdge.e_folds`) reaches this (``exp(-5)``: under 1% of the initial error
    left). Until every edge is, each of its owners adds ``e_high`` to its share of ``E``, so the
    gate ``k_E(E)`` of eq. 16 keeps the active motion on: ``E`` alone is also small while an edge
    that was barely excited is still wrong (demo runs stalled at 4% this way). Not in the paper."""
    # formation (paper 002 eq. 20) and yaw alignment
    k_formation: float = 0.5
    k_yaw: float = 1.0
    # random-motion baseline
    random_tau_s: float = 1.0
    # safety
    v_max_m_s: float = 3.0
    yaw_rate_max_rad_s: float = 1.5
    peer_timeout_s: float = 0.5
    # rigidity maintenance (paper 003); defaults are the rigidity scenarios' values
    rigidity_maintenance: bool = False
    """Add the rigidity-maintenance action (eq. 19-23) and collision avoidance to the mode's
    command. Mode ``rigidity-tracking`` without it is the paper's "maintenance off" baseline."""
    rigidity_edges: tuple[tuple[int, int], ...] = ()
    """The rigidity layer's graph (default: ``edges``): ``(i, j)`` when ``i``'s camera may see
    ``j``. Its angles make the weighted rigidity matrix, and its out-neighbours are the
    candidates of the eigen-estimate; the sensing weights drop the ones out of view. With an
    all-round camera the complete graph is the graph the cameras actually sense, and the
    formation's own (sparser) edges would understate the rigidity the team has."""
    rigidity_eigen: Literal["distributed", "centralized"] = "distributed"
    """Where ``lambda`` and its gradient come from: the distributed power iteration, or every
    agent's shared estimate (needs all-to-all communication)."""
    rigidity_scale_from_sfm: bool = False
    """Use SfM distances (paper 000) as the scale of angle localization besides ranges."""
    fov_deg: float = 120.0
    range_m: float = 15.0
    lambda_min: float = 0.02
    lambda_safe: float = 0.2
    k_rigidity: float = 0.05
    r_coll_m: float = 0.6
    r_safe_m: float = 1.5
    k_collision: float = 1.0
    track_target: int = -1
    """Mission target this agent tracks (-1: none)."""
    r_track_m: float = 2.0
    k_track_range: float = 0.15
    k_track_camera: float = 0.4
    k_angle_loc: float = 4.0
    k_distance_loc: float = 1.0
    k_vertical_loc: float = 4.0
    """Gain of the gravity (bearing elevation) term of angle localization; 0 = angles only."""
    rigidity_softmin_tau: float = 0.01
    """The rigidity action follows the gradient of a smooth minimum of the tracked modes' eigenvalues
    at this temperature (:func:`onboard.control.rigidity.softmin_weights`; 0: the smallest
    mode alone, as in paper 003)."""
    eigen_columns: int = 3
    eigen_step: float = 1.5
    eigen_k_t: float = 0.3
    eigen_k_n: float = 0.2
    """Distributed eigen-estimation (:class:`onboard.estimation.distributed_eigen.EigenGains`):
    vectors tracked, power step over the degree bound, per-round consensus gains."""
    rigidity_period_s: float = 0.0
    """The rigidity layer steps at most this often (0: every core step), integrating over the
    time since its last step. It is a slow outer loop and costs several times the rest of the
    core; the daemons' 6 x 100 Hz of it did not fit on two cores."""
    rigidity_warmup_s: float = 0.0
    """Seconds after the first step during which the rigidity layer's actions are zero, so
    angle localization and the eigen-estimate converge before the team moves."""

    def __post_init__(self) -> None:
        n = self.n_agents
        if not 0 <= self.agent_id < n:
            raise ValueError(f"agent_id {self.agent_id} outside 0..{n - 1}")
        for i, j in (*self.edges, *self.rigidity_edges):
            if not (0 <= i < n and 0 <= j < n) or i == j:
                raise ValueError(f"bad edge ({i}, {j}) for {n} agents")
        if len(self.p_hat0_ned) not in (0, n) or len(self.yaw_hat0_rad) not in (0, n):
            raise ValueError("p_hat0_ned and yaw_hat0_rad need one entry per agent")
        if self.mode in ("formation", "formation-active") and not self.desired_beta_body:
            raise ValueError(f"mode {self.mode!r} needs desired_beta_body")
        if self.excitation_relay_every < 1:
            raise ValueError("excitation_relay_every must be >= 1")
        if self.p_norm >= 0.0:
            raise ValueError("p_norm must be negative (a soft minimum)")
        for name in ("sfm_bias_speed_m_s", "sfm_folds_forget_s", "sfm_wander_max"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not self.sfm_wander_window_s > 0.0:
            raise ValueError(f"sfm_wander_window_s must be > 0, got {self.sfm_wander_window_s}")

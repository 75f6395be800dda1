"""Paper 002's simulations in the headless runner (fig. 11 and the localization problems).

The paper does not print its fig. 11 formations, so this module fixes its own, in the same
spirit (where the paper is silent, the choices are stated here):

* ``formation-2d-bearing`` (fig. 11a): **7 agents in 2-D**, desired formation a regular hexagon of
  radius 3 m around a centre agent, sensing graph the 6 spokes and the 6 rim edges, both
  directions (24 directed edges, bearing rigid); random initial positions uniform in a 12 m square;
  bearings only, ``f_C(c) = 1 - c``, ``k = 0.5``, ``dt = 10 ms``, 60 s. The scale is not
  controlled (the flow only shrinks it): ``final_scale`` reports the final mean edge length over
  the desired one, ``final_distance_error_m`` is ``null``.
* ``formation-2d-range`` (fig. 11b): the same plus **one range** (edge 0 -> 1) with
  ``f_D(x) = x^2`` (eq. 23): the formation reaches the desired size.
* ``formation-3d-range`` (fig. 11c): **11 agents in 3-D**: a 5-agent ring (radius 3 m), a second
  5-agent ring 2.5 m above it (radius 2 m, turned 36 degrees) and an apex; edges: both rings,
  the antiprism between them and the apex to the upper ring (25 pairs, both directions, 4-6
  bearings per agent, bearing rigid), random start in a 12 m cube, one range.
* ``localization-bearing``: **N = 10** agents uniform in a 10 m cube, graph the ring with hops 1
  and 3 (both directions, 40 edges), rotations known, random initial estimates (translations
  ``N(0, 5 m)``, scales uniform in [1, 4]); bearing-only localization with ``lambda >= 1``
  (eq. 16-17). ``final_position_error_m``: largest error after the best scale + translation
  (the rotations are known, so the frame is fixed).
* ``localization-rotation``: the same agents and graph with random true attitudes anywhere in
  SO(3); measured relative rotations perturbed by 2 degrees (Gaussian rotation vector, 2 degrees
  per axis... scaled so the RMS angle is 2 degrees); random initial rotations anywhere in SO(3);
  rotation estimation with ``f_R`` (eq. 13-15, ``b = 2``), then bearing localization from the
  body bearings turned into the estimated frame (the paper's experiment runs rotations first,
  then translations). ``final_rotation_error_deg``: largest error after the best global rotation;
  ``final_position_error_m`` after the best similarity.

Localization runs count message rounds: ``duration_s`` at a 100 Hz message rate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from onboard.distributed.formation import bearings_from_positions
from onboard.distributed.metrics import position_error_m, rotation_error_deg
from onboard.distributed.reshaping import F_R, ReshapeD
from onboard.distributed.rotation import relative_rotations
from onboard.distributed.solvers import estimate_rotations, localize
from onboard.geometry import FloatArray, so3_exp
from sim.formation2d import FormationProblem, FormationRun, run_formation

CONVERGED_BEARING_DEG = 0.5
"""A formation run converged when every bearing is within this of the desired one."""
CONVERGED_DISTANCE_M = 0.05
"""... and, with a range, every distance within this of the desired one."""
ROUNDS_PER_S = 100.0
K_GAIN = 1.5
"""``k`` of eq. 7 for the formations (m/s per unit gradient)."""
DT_S = 0.005
"""Formation step; ``dt k`` is inside the displacement rule for every problem here."""
F_D_FORMATION = ReshapeD(w=5.0)
"""``f_D(x) = 5 x^2`` for the range term of eq. 23."""
GRAD_TOL = 1e-6
"""Localization stops when every gradient entry is below this (then ``converged``)."""
ROTATION_NOISE_DEG = 2.0


def _both(und: list[tuple[int, int]]) -> np.ndarray:
    return np.array([*und, *[(j, i) for i, j in und]], dtype=np.int64)


def hexagon_problem(ranged: bool) -> FormationProblem:
    ang = np.arange(6) * np.pi / 3.0
    p = np.vstack([[0.0, 0.0], 3.0 * np.stack([np.cos(ang), np.sin(ang)], axis=1)])
    und = [(0, i) for i in range(1, 7)] + [(i, i % 6 + 1) for i in range(1, 7)]
    e = _both(und)
    r = np.zeros(len(e), dtype=bool)
    r[0] = ranged
    return FormationProblem(p_des=p, edges=e, ranged=r)


def antiprism_problem() -> FormationProblem:
    a = np.arange(5) * 2 * np.pi / 5
    low = np.stack([3 * np.cos(a), 3 * np.sin(a), np.zeros(5)], axis=1)
    b = a + np.pi / 5
    up = np.stack([2 * np.cos(b), 2 * np.sin(b), np.full(5, -2.5)], axis=1)
    p = np.vstack([low, up, [[0.0, 0.0, -4.0]]])
    und = [(i, (i + 1) % 5) for i in range(5)] + [(5 + i, 5 + (i + 1) % 5) for i in range(5)]
    und += [(i, 5 + i) for i in range(5)] + [(i, 5 + (i - 1) % 5) for i in range(5)]
    und += [(5 + i, 10) for i in range(5)]
    e = _both(und)
    r = np.zeros(len(e), dtype=bool)
    r[0] = True
    return FormationProblem(p_des=p, edges=e, ranged=r)


def ring_graph(n: int = 10, hops: tuple[int, ...] = (1, 3)) -> np.ndarray:
    return _both([(i, (i + h) % n) for h in hops for i in range(n)])


@dataclass(frozen=True)
class FormationScenario:
    name: str
    figure: str
    problem: FormationProblem
    box_m: float


@dataclass
class FormationResult:
    name: str
    seed: int
    problem: FormationProblem
    run: FormationRun
    extra: dict[str, object] = field(default_factory=dict)

    def summary(self) -> dict[str, object]:
        be = float(self.run.bearing_error_deg[-1].max())
        has_range = bool(self.problem.ranged.any())
        de = float(self.run.distance_error_m[-1].max()) if has_range else None
        e = self.problem.edges
        p = self.run.p[-1]
        d = np.linalg.norm(p[e[:, 1]] - p[e[:, 0]], axis=1)
        d_des = np.linalg.norm(self.problem.p_des[e[:, 1]] - self.problem.p_des[e[:, 0]], axis=1)
        converged = be < CONVERGED_BEARING_DEG and (de is None or de < CONVERGED_DISTANCE_M)
        return {
            "scenario": self.name,
            "seed": self.seed,
            "n_agents": int(p.shape[0]),
            "dim": int(p.shape[1]),
            "n_edges": len(e),
            "initial_bearing_error_deg": float(self.run.bearing_error_deg[0].max()),
            "final_bearing_error_deg": be,
            "final_distance_error_m": de,
            "final_scale": float(d.mean() / d_des.mean()),
            "dropped_edge_steps": self.run.dropped_edges,
            "converged": bool(converged),
            **self.extra,
        }


@dataclass
class LocalizationOutcome:
    name: str
    seed: int
    p_true: FloatArray
    p_est: FloatArray
    edges: np.ndarray
    cost: FloatArray
    position_error_m: float
    rotation_error_deg: float
    rounds: int
    stationary: bool
    rotation_cost: FloatArray | None = None

    def summary(self) -> dict[str, object]:
        return {
            "scenario": self.name,
            "seed": self.seed,
            "n_agents": int(self.p_true.shape[0]),
            "n_edges": len(self.edges),
            "rounds": self.rounds,
            "final_cost": float(self.cost[-1]),
            "final_position_error_m": self.position_error_m,
            "final_rotation_error_deg": self.rotation_error_deg,
            "converged": self.stationary,
        }


FORMATION_SCENARIOS: dict[str, FormationScenario] = {
    s.name: s
    for s in (
        FormationScenario("formation-2d-bearing", "11a", hexagon_problem(False), 12.0),
        FormationScenario("formation-2d-range", "11b", hexagon_problem(True), 12.0),
        FormationScenario("formation-3d-range", "11c", antiprism_problem(), 12.0),
    )
}
LOCALIZATION_SCENARIOS = ("localization-bearing", "localization-rotation")
DISTRIBUTED_SCENARIOS = [*FORMATION_SCENARIOS, *LOCALIZATION_SCENARIOS]
"""Every paper-002 scenario name (the scenario CLI's registry)."""


def run_formation_scenario(
    name: str, seed: int = 0, duration_s: float = 60.0, bearing_noise_rad: float = 0.0
) -> FormationResult:
    sc = FORMATION_SCENARIOS[name]
    rng = np.random.default_rng(seed)
    half = sc.box_m / 2
    p0 = rng.uniform(-half, half, sc.problem.p_des.shape)
    run = run_formation(
        sc.problem,
        p0,
        duration_s,
        dt_s=DT_S,
        k=K_GAIN,
        f_d=F_D_FORMATION,
        bearing_noise_rad=bearing_noise_rad,
        seed=seed,
    )
    return FormationResult(name=name, seed=seed, problem=sc.problem, run=run)


def run_localization_scenario(
    name: str, seed: int = 0, duration_s: float = 1000.0, bearing_noise_rad: float = 0.0
) -> LocalizationOutcome:
    if name not in LOCALIZATION_SCENARIOS:
        raise ValueError(f"unknown localization scenario {name!r}")
    rng = np.random.default_rng(seed)
    n = 10
    e = ring_graph(n)
    p = rng.uniform(-5, 5, (n, 3))
    b, _ = bearings_from_positions(p, e)
    rounds = max(1, round(duration_s * ROUNDS_PER_S))
    if bearing_noise_rad > 0:
        b = b + rng.normal(0, bearing_noise_rad, b.shape)
        b /= np.linalg.norm(b, axis=1)[:, None]
    if name == "localization-bearing":
        res = localize(
            e, b, rng.normal(0, 5, (n, 3)), rng.uniform(1, 4, len(e)), rounds, grad_tol=GRAD_TOL
        )
        return LocalizationOutcome(
            name,
            seed,
            p,
            res.t,
            e,
            res.cost,
            position_error_m(res.t, p, rotate=False),
            0.0,
            res.rounds,
            stationary=res.rounds < rounds,
        )
    r_true = so3_exp(_uniform_rotvec(rng, n))
    beta = np.einsum("eba,eb->ea", r_true[e[:, 0]], b)  # body bearings
    sig = np.radians(ROTATION_NOISE_DEG) / np.sqrt(3.0)
    meas = relative_rotations(r_true, e) @ so3_exp(rng.normal(0, sig, (len(e), 3)))
    rot = estimate_rotations(
        e, meas, so3_exp(_uniform_rotvec(rng, n)), rounds, F_R, grad_tol=GRAD_TOL
    )
    u = np.einsum("eab,eb->ea", rot.rot[e[:, 0]], beta)
    res = localize(
        e, u, rng.normal(0, 5, (n, 3)), rng.uniform(1, 4, len(e)), rounds, grad_tol=GRAD_TOL
    )
    return LocalizationOutcome(
        name,
        seed,
        p,
        res.t,
        e,
        res.cost,
        position_error_m(res.t, p, rotate=True),
        rotation_error_deg(rot.rot, r_true),
        rot.rounds + res.rounds,
        stationary=rot.rounds < rounds and res.rounds < rounds,
        rotation_cost=rot.cost,
    )


def _uniform_rotvec(rng: np.random.Generator, n: int) -> FloatArray:
    """Rotation vectors of rotations uniform on SO(3) (from uniform unit quaternions)."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q *= np.sign(q[:, :1] + (q[:, :1] == 0))
    ang = 2 * np.arccos(np.clip(q[:, 0], -1, 1))
    s = np.linalg.norm(q[:, 1:], axis=1)
    axis = np.where(s[:, None] > 1e-12, q[:, 1:] / np.maximum(s, 1e-12)[:, None], 0.0)
    return axis * ang[:, None]


def run_distributed_scenario(
    name: str, seed: int = 0, duration_s: float | None = None, bearing_noise_rad: float = 0.0
) -> FormationResult | LocalizationOutcome:
    """Run any paper-002 scenario (defaults: 60 s formations, 1000 s = 100000 rounds localization, which stop early once stationary)."""
    if name in FORMATION_SCENARIOS:
        return run_formation_scenario(name, seed, duration_s or 60.0, bearing_noise_rad)
    if name in LOCALIZATION_SCENARIOS:
        return run_localization_scenario(name, seed, duration_s or 1000.0, bearing_noise_rad)
    raise ValueError(f"unknown scenario {name!r}; choose from {', '.join(DISTRIBUTED_SCENARIOS)}")

"""Paper 003's two simulations (sec. 5.2) in the headless runner: rigidity maintenance while
tracking moving targets with narrow cameras.

The paper's numbers lost their symbols in extraction; the choices here, where it is silent:

* ``rigidity-tracking`` (first simulation, fig. 2-3): **N = 5** robots (the text: three robots
  turn away, "the maximum possible", and "the remaining two" keep rigidity), random start in a
  **4 m cube** centred 6 m up (at least 1.2 m apart), cameras (body x, level) toward the
  barycenter. **Three targets** tracked by robots 0, 1, 2, starting about 6 m from the
  barycenter in three directions 120 degrees apart and moving on slow, seeded Lissajous paths
  inside a 16 m cube. Robots 3 and 4 measure their distance (a range radio) for the scale.
* ``rigidity-tracking-off``: the same with the rigidity term off (collision avoidance and
  tracking only).
* ``rigidity-sphere`` (second simulation, fig. 4-5): **N = 6** robots and **one fast target**
  on a sphere of radius 9 m around the initial barycenter (great circle at 0.25 rad/s, about
  2.3 m/s, whose plane precesses); every robot points its camera at it (no tracking radius).
* Camera: **fov 120 deg, range 15 m** (weights roll off over the outer 20 %: full weight to
  48 deg and 12 m). Collision: ``r_coll = 0.6 m``, ``r_safe = 1.5 m``. Barrier levels
  ``lambda_min = 0.02``, ``lambda_safe = 0.2`` (the weighted eigenvalue of the random starts
  is 0.1-0.6). Tracking gains ``k_r = 0.15``, ``k_c = 0.4`` (yaw rate up to 0.4 rad/s), tracking
  radius 2 m; speeds are saturated at 3 m/s and 1.5 rad/s.
* Localization prior: truth plus 0.3 m Gaussian noise per axis (the paper samples around the
  truth too). Before the mission starts the team hovers for ``WARMUP_S`` = 4 s while angle
  localization and the distributed eigen-estimate converge; the targets wait as well.
* Starts are resampled until the weighted eigenvalue is at least ``START_LAMBDA`` = 0.1: with
  a 120 deg camera about a third of the random cube starts are (nearly) flexible, which the
  paper's "all robots engaged in mutual sensing" start excludes.
* Loop 500 Hz, also the message rate (paper 000's 2 ms), bearings at 50 Hz, 60 s missions.
  The distributed eigen-estimate's gains are per message round
  (:class:`onboard.estimation.distributed_eigen.EigenGains`), so the same values serve a 2 ms
  and a 10 ms period. (The earlier single-vector power iteration lagged the drop of the
  eigenvalue when its two smallest non-trivial modes crossed, and the team lost rigidity in
  9 of 10 seeds; the subspace iteration with Rayleigh-Ritz follows the crossing.)

Truth is used only here, for the evaluation: the weighted eigenvalue of the true
configuration, the rigidity of the true sensing graph, target visibility and the
localization error (after the best rotation and translation, the estimator's free motions).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from onboard.core.agent import AgentCore
from onboard.core.config import AgentConfig, build_config
from onboard.core.rigidity import UNCERTAINTY_LAG_S, estimate_uncertain, lag_uncertainty
from onboard.geometry import FloatArray, camera_axis_ned
from onboard.graph import angle_set, complete_graph, sensing_graph
from onboard.rigidity.angle import (
    angle_rigidity_eigenvalue,
    is_infinitesimally_angle_rigid,
    weighted_angle_rigidity_eigenvalue,
)
from onboard.rigidity.weights import SensingModel
from sim.runner import Recording, RunnerConfig, run

FOV_DEG = 120.0
RANGE_M = 15.0
WARMUP_S = 4.0
DT_S = 0.002
START_LAMBDA = 0.1
"""Random starts are resampled until their weighted eigenvalue reaches this (the paper's start
is "sufficiently dense": every robot engaged in mutual sensing)."""
LOCALIZATION_PRIOR_SIGMA_M = 0.3
RIGID_TOL = 1e-4
"""The weighted eigenvalue below this counts as "rigidity lost" (the paper's ``lambda = 0``)."""
EXCURSION_REL = 0.10
"""A distributed estimate further than this from the centralized value is an excursion (issue
30); the summary counts how many the ``rigidity_uncertain`` alarm flags."""


@dataclass(frozen=True)
class RigidityScenario:
    name: str
    n_agents: int
    maintenance: bool
    kind: Literal["tracking", "sphere"]
    description: str


RIGIDITY_SCENARIOS: dict[str, RigidityScenario] = {
    s.name: s
    for s in (
        RigidityScenario(
            "rigidity-tracking", 5, True, "tracking", "3 moving targets, rigidity maintenance on"
        ),
        RigidityScenario(
            "rigidity-tracking-off", 5, False, "tracking", "same, rigidity maintenance off"
        ),
        RigidityScenario(
            "rigidity-sphere", 6, True, "sphere", "1 fast target on a sphere, maintenance on"
        ),
    )
}


def initial_configuration(n: int, seed: int) -> tuple[FloatArray, FloatArray]:
    """Random start in a 4 m cube 6 m up, >= 1.2 m apart, cameras toward the barycenter, and
    (resampled until) rigid with margin: weighted eigenvalue >= ``START_LAMBDA``."""
    rng = np.random.default_rng([seed, 3003])
    model = SensingModel(FOV_DEG, RANGE_M)
    edges = complete_graph(n)
    while True:
        p = rng.uniform(-2.0, 2.0, (n, 3)) + np.array([0.0, 0.0, -6.0])
        d = np.linalg.norm(p[:, None] - p[None], axis=-1) + 10.0 * np.eye(n)
        if d.min() < 1.2:
            continue
        c = p.mean(axis=0)
        yaw = np.arctan2(c[1] - p[:, 1], c[0] - p[:, 0])
        if weighted_angle_rigidity_eigenvalue(p, yaw, edges, model)[0] >= START_LAMBDA:
            return p, yaw


def target_path(name: str, seed: int, center: ArrayLike) -> Callable[[float], FloatArray]:
    """True target positions ``(T, 3)`` as a function of time (still during the warm-up)."""
    c = np.asarray(center, dtype=float)
    rng = np.random.default_rng([seed, 77])
    if RIGIDITY_SCENARIOS[name].kind == "sphere":
        radius, rate, precession = 9.0, 0.25, 0.05
        tilt = rng.uniform(0.3, 0.8)
        phase = rng.uniform(0.0, 2.0 * np.pi)

        def sphere(t: float) -> FloatArray:
            s = max(t - WARMUP_S, 0.0)
            a = phase + rate * s
            n_ang = precession * s
            # great circle in a plane tilted by `tilt`, its normal precessing about the vertical
            u = np.array([math.cos(n_ang), math.sin(n_ang), 0.0])
            w = np.array(
                [
                    -math.sin(n_ang) * math.cos(tilt),
                    math.cos(n_ang) * math.cos(tilt),
                    math.sin(tilt),
                ]
            )
            return (c + radius * (math.cos(a) * u + math.sin(a) * w))[None, :]

        return sphere

    base = rng.uniform(0.0, 2.0 * np.pi)
    azim = base + np.array([0.0, 2.0, 4.0]) * np.pi / 3.0
    start = c + np.stack(
        [6.0 * np.cos(azim), 6.0 * np.sin(azim), rng.uniform(-1.0, 1.0, 3)], axis=1
    )
    amp = rng.uniform([1.5, 1.5, 0.5], [3.0, 3.0, 1.0], (3, 3))
    freq = rng.uniform(0.05, 0.12, (3, 3))

    def lissajous(t: float) -> FloatArray:
        s = max(t - WARMUP_S, 0.0)
        return start + amp * np.sin(freq * s)

    return lissajous


def agent_configs(
    name: str, seed: int = 0, **overrides: object
) -> tuple[list[AgentConfig], FloatArray, FloatArray]:
    """Configs of scenario ``name`` and the true initial ``(p0, yaw0)``."""
    sc = RIGIDITY_SCENARIOS[name]
    n = sc.n_agents
    p0, yaw0 = initial_configuration(n, seed)
    prior = p0 + np.random.default_rng([seed, 11]).normal(
        scale=LOCALIZATION_PRIOR_SIGMA_M, size=p0.shape
    )
    edges = tuple((int(i), int(j)) for i, j in complete_graph(n))
    options: dict[str, object] = {
        "mode": "rigidity-tracking",
        "rigidity_maintenance": sc.maintenance,
        "fov_deg": FOV_DEG,
        "range_m": RANGE_M,
        "rigidity_warmup_s": WARMUP_S,
        "p_hat0_ned": tuple(tuple(float(x) for x in row) for row in prior),
        "seed": seed,
    }
    if sc.kind == "sphere":
        options.update(k_track_range=0.0)
    options.update(overrides)
    configs = []
    for i in range(n):
        track = (i if i < 3 else -1) if sc.kind == "tracking" else 0
        configs.append(
            build_config(agent_id=i, n_agents=n, edges=edges, track_target=track, **options)
        )
    return configs, p0, yaw0


@dataclass
class RigidityRecording:
    """A run plus what the agents estimated, sampled with the runner's recording."""

    rec: Recording
    name: str
    seed: int
    targets_ned: FloatArray  # (T, M, 3)
    lambda_hat: FloatArray  # (T, N) each agent's eigenvalue estimate
    p_hat_ned: FloatArray  # (T, N, 3) angle-localization estimates
    yaw_hat_rad: FloatArray  # (T, N) yaws in the estimated frame
    track_target: list[int]
    model: SensingModel
    lambda_min: float
    lambda_safe: float
    warmup_s: float
    _cache: dict[str, FloatArray] = field(default_factory=dict)

    def _get(self, key: str, fn: Callable[[], FloatArray]) -> FloatArray:
        if key not in self._cache:
            self._cache[key] = fn()
        return self._cache[key]

    @property
    def lambda_true(self) -> FloatArray:
        """Weighted eigenvalue of the true configuration ``(T,)`` (paper 003 eq. 16)."""
        edges = complete_graph(self.p_hat_ned.shape[1])
        return self._get(
            "lambda_true",
            lambda: np.array(
                [
                    weighted_angle_rigidity_eigenvalue(p, y, edges, self.model)[0]
                    for p, y in zip(self.rec.p_ned, self.rec.yaw_rad, strict=True)
                ]
            ),
        )

    @property
    def lambda_unweighted(self) -> FloatArray:
        """Unweighted eigenvalue of the true sensing graph, scaled by the mean squared distance
        (as the paper scales it for fig. 3a) ``(T,)``; 0 when the graph has too few angles."""

        def compute() -> FloatArray:
            out = []
            for p, y in zip(self.rec.p_ned, self.rec.yaw_rad, strict=True):
                e = sensing_graph(p, y, self.model.fov_deg, self.model.range_m)
                a = angle_set(e)
                if len(a) < 1:
                    out.append(0.0)
                    continue
                d2 = np.mean(np.sum((p[e[:, 1]] - p[e[:, 0]]) ** 2, axis=1))
                out.append(max(angle_rigidity_eigenvalue(p, a), 0.0) * d2)
            return np.array(out)

        return self._get("lambda_unweighted", compute)

    @property
    def rigid(self) -> FloatArray:
        """True sensing graph infinitesimally angle rigid, per sample ``(T,)`` (bool)."""
        return self._get(
            "rigid",
            lambda: np.array(
                [
                    is_infinitesimally_angle_rigid(
                        p, sensing_graph(p, y, self.model.fov_deg, self.model.range_m)
                    )
                    for p, y in zip(self.rec.p_ned, self.rec.yaw_rad, strict=True)
                ]
            ),
        )

    @property
    def lambda_central_est(self) -> FloatArray:
        """Centralized weighted eigenvalue of the *estimated* configuration ``(T,)``: what the
        distributed estimate should match."""
        edges = complete_graph(self.p_hat_ned.shape[1])
        return self._get(
            "lambda_central_est",
            lambda: np.array(
                [
                    weighted_angle_rigidity_eigenvalue(p, y, edges, self.model)[0]
                    for p, y in zip(self.p_hat_ned, self.yaw_hat_rad, strict=True)
                ]
            ),
        )

    @property
    def target_angle_deg(self) -> FloatArray:
        """Angle between each robot's camera axis and its bearing to each target ``(T, N, M)``."""
        r = self.targets_ned[:, None, :, :] - self.rec.p_ned[:, :, None, :]
        b = r / np.linalg.norm(r, axis=-1, keepdims=True)
        c = camera_axis_ned(self.rec.yaw_rad)
        return np.degrees(np.arccos(np.clip(np.einsum("tnd,tnmd->tnm", c, b), -1.0, 1.0)))

    @property
    def localization_error(self) -> FloatArray:
        """RMS position error after the best rotation + translation ``(T,)``."""
        return self._get(
            "loc_err",
            lambda: np.array(
                [
                    rigid_alignment_error(ph, p)
                    for ph, p in zip(self.p_hat_ned, self.rec.p_ned, strict=True)
                ]
            ),
        )

    @property
    def eigen_flagged(self) -> FloatArray:
        """Where each agent's ``rigidity_uncertain`` alarm is raised ``(T, N)`` (bool): the
        layer's :func:`onboard.core.rigidity.lag_uncertainty` on the recorded estimates (the
        record period is the layer's measuring period, 0.1 s)."""
        lam = self.lambda_hat
        t = self.rec.t_s
        rate = np.zeros(lam.shape[1])
        out = np.zeros(lam.shape, dtype=bool)
        for k in range(1, len(t)):
            for i in range(lam.shape[1]):
                rate[i] = lag_uncertainty(rate[i], lam[k - 1, i], lam[k, i], t[k] - t[k - 1])
                out[k, i] = estimate_uncertain(lam[k, i], UNCERTAINTY_LAG_S * rate[i])
        return out

    def summary(self) -> dict[str, object]:
        t = self.rec.t_s
        lam = self.lambda_true
        mission = t >= self.warmup_s
        if not np.any(mission):  # a run shorter than the warm-up: evaluate all of it
            mission = np.ones_like(t, dtype=bool)
        visible = self.target_angle_deg[-1] <= self.model.fov_deg / 2.0
        after = t >= min(self.warmup_s + 1.0, t[-1])
        central = self.lambda_central_est
        rel = np.abs(self.lambda_hat - central[:, None]) / np.maximum(central[:, None], 1e-9)
        valid = after & (central > self.lambda_min)
        loc = self.localization_error
        flagged = self.eigen_flagged
        excursion = (rel > EXCURSION_REL) & valid[:, None]
        trusted = (rel <= EXCURSION_REL) & valid[:, None]
        return {
            "scenario": self.name,
            "seed": self.seed,
            "min_rigidity_eigenvalue": float(lam[mission].min()),
            "lambda_min": self.lambda_min,
            "stayed_above_lambda_min": bool(lam[mission].min() > self.lambda_min),
            "rigidity_lost": bool(lam[mission].min() < RIGID_TOL),
            "fraction_time_rigid": float(np.mean(self.rigid[mission])),
            "targets_tracked": int(np.sum(np.any(visible, axis=0))),
            "n_targets": int(self.targets_ned.shape[1]),
            "initial_localization_error": float(loc[0]),
            "final_localization_error": float(loc[-1]),
            "max_localization_error_after_warmup": float(loc[mission].max()),
            "distributed_eigen_error_max": float(rel[valid].max()) if np.any(valid) else None,
            "distributed_eigen_error_p95": float(np.percentile(rel[valid], 95))
            if np.any(valid)
            else None,
            "distributed_eigen_excursions": int(excursion.sum()),
            "distributed_eigen_excursions_flagged": float((excursion & flagged).sum())
            / max(int(excursion.sum()), 1),
            "distributed_eigen_false_alarm_rate": float((trusted & flagged).sum())
            / max(int(trusted.sum()), 1),
            "distributed_vs_true_error_median": float(
                np.median(
                    np.abs(self.lambda_hat[after] - lam[after, None])
                    / np.maximum(lam[after, None], 1e-9)
                )
            ),
        }


def rigid_alignment_error(p_est: ArrayLike, p_true: ArrayLike) -> float:
    """RMS error (m) after the rotation and translation (Kabsch, no scaling) that best fit."""
    a = np.asarray(p_est, dtype=float)
    b = np.asarray(p_true, dtype=float)
    a0, b0 = a - a.mean(axis=0), b - b.mean(axis=0)
    u, _, vt = np.linalg.svd(a0.T @ b0)
    r = u @ np.diag([1.0, 1.0, float(np.sign(np.linalg.det(u @ vt)))]) @ vt
    return float(np.sqrt(np.mean(np.sum((a0 @ r - b0) ** 2, axis=1))))


def run_rigidity_scenario(
    name: str,
    seed: int = 0,
    duration_s: float = 60.0,
    progress: Callable[[float], None] | None = None,
    config_overrides: dict[str, object] | None = None,
    engine: str = "cores",
    **runner_options: object,
) -> RigidityRecording:
    """Run rigidity scenario ``name``; ``runner_options`` go to :class:`sim.runner.RunnerConfig`.

    ``engine``: ``"cores"`` steps one agent core per vehicle (the reference), ``"compiled"`` the
    same team in :mod:`sim.compiled_rigidity`."""
    if engine not in ("cores", "compiled"):
        raise ValueError(f"unknown engine {engine!r}; choose 'cores' or 'compiled'")
    if name not in RIGIDITY_SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; choose from {', '.join(RIGIDITY_SCENARIOS)}")
    configs, p0, yaw0 = agent_configs(name, seed, **(config_overrides or {}))
    path = target_path(name, seed, p0.mean(axis=0))
    sc = RIGIDITY_SCENARIOS[name]
    options: dict[str, object] = {
        "dt_s": DT_S,
        "record_every": 50,
        "fov_deg": FOV_DEG,
        "sensing_range_m": RANGE_M,
        "range_pairs": ((3, 4),),
        "target_path": path,
    }
    options.update(runner_options)
    rc = RunnerConfig(duration_s=duration_s, seed=seed, **options)  # type: ignore[arg-type]
    n_rec = round(duration_s / rc.dt_s) // rc.record_every + 1
    n = sc.n_agents
    lam = np.zeros((n_rec, n))
    p_hat = np.zeros((n_rec, n, 3))
    yaw_hat = np.zeros((n_rec, n))
    targets = np.zeros((n_rec, len(path(0.0)), 3))

    def on_record(r: int, t: float, cores: list[AgentCore]) -> None:
        targets[r] = path(t)
        for i, core in enumerate(cores):
            layer = core.rigidity
            assert layer is not None
            lam[r, i] = layer.lambda_hat
            p_hat[r, i] = layer.loc.p_hat_ned
            yaw_hat[r, i] = layer.yaw_hat

    if engine == "compiled":
        from sim.compiled_rigidity import run_compiled_rigidity_team

        rec, lam, p_hat, yaw_hat, _ = run_compiled_rigidity_team(configs, p0, yaw0, rc, path)
        for r, t in enumerate(rec.t_s.tolist()):
            targets[r] = path(t)
        if progress is not None:
            progress(1.0)
    else:
        rec = run(configs, p0, yaw0, rc, progress, on_record=on_record)  # type: ignore[arg-type]
    cfg = configs[0].rigidity
    return RigidityRecording(
        rec=rec,
        name=name,
        seed=seed,
        targets_ned=targets,
        lambda_hat=lam,
        p_hat_ned=p_hat,
        yaw_hat_rad=yaw_hat,
        track_target=[c.rigidity.track_target for c in configs],
        model=SensingModel(cfg.fov_deg, cfg.range_m),
        lambda_min=cfg.lambda_min,
        lambda_safe=cfg.lambda_safe,
        warmup_s=cfg.rigidity_warmup_s,
    )

"""The virtual camera: each vehicle's body-frame bearings to the vehicles it can see.

A camera looks along body x of a level vehicle with a circular field of view ``fov_deg`` (full
cone angle) and a range ``range_m`` — the sensing model of :func:`onboard.graph.sensing_graph`.
Vehicle ``i`` sees ``j`` when ``c_i . b_ij >= cos(fov / 2)`` and ``d_ij <= range``, and measures
``beta_ij = R_z(psi_i)^T (p_j - p_i) / d_ij`` (equations.md, "Conventions"), optionally
perturbed by an isotropic angular noise and randomly dropped. With zero noise and dropout the
bearings are exact.

:class:`CameraPublisher` is the small I/O part: a tick hook for :class:`sim.server.SimServer`
that, at the camera rate (simulation time), publishes one :class:`messages.sim.CameraBearings`
per vehicle and, separately, its :class:`messages.sim.Truth` through a ``put(key, bytes)``
callable (Zenoh in the CLI, a list in tests).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from messages.codec import encode
from messages.sim import CameraBearings, Truth, camera_key, truth_key
from onboard.geometry import FloatArray, IntArray, bearings_body
from onboard.graph import sensing_graph
from sim.world import World


@dataclass(frozen=True)
class CameraConfig:
    """Camera model shared by all vehicles."""

    fov_deg: float = 90.0
    range_m: float = 25.0
    noise_std_rad: float = 0.0
    """Standard deviation of the angular error of each bearing (per tangent axis)."""
    dropout: float = 0.0
    """Probability that a visible vehicle is missed in one frame."""
    rate_hz: float = 30.0
    seed: int = 0
    unsynchronized: bool = False
    """Each vehicle's camera runs at its own phase (drawn from ``seed``, uniform over a frame
    period) instead of every camera at the same instant: real cameras on different vehicles
    are not synchronized, so an own frame and a neighbour's never share a stamp (the realistic
    dynamics turn it on)."""

    def __post_init__(self) -> None:
        if not 0.0 < self.fov_deg <= 360.0:
            raise ValueError(f"fov_deg must be in (0, 360], got {self.fov_deg}")
        if not self.range_m > 0.0:
            raise ValueError(f"range_m must be > 0, got {self.range_m}")
        if not self.noise_std_rad >= 0.0:
            raise ValueError(f"noise_std_rad must be >= 0, got {self.noise_std_rad}")
        if not 0.0 <= self.dropout <= 1.0:
            raise ValueError(f"dropout must be in [0, 1], got {self.dropout}")
        if not self.rate_hz > 0.0:
            raise ValueError(f"rate_hz must be > 0, got {self.rate_hz}")


def visible_bearings(
    p_ned: FloatArray, yaw_rad: FloatArray, fov_deg: float, range_m: float
) -> tuple[IntArray, FloatArray, FloatArray]:
    """Edges ``(i, j)`` with ``j`` in ``i``'s field of view and range, their exact body-frame
    bearings ``beta_ij`` ``(E, 3)`` and distances ``d_ij`` ``(E,)``."""
    edges = sensing_graph(p_ned, yaw_rad, fov_deg, range_m)
    if len(edges) == 0:
        return edges, np.zeros((0, 3)), np.zeros(0)
    beta, d = bearings_body(p_ned, yaw_rad, edges)
    return edges, beta, d


Vec3 = tuple[float, float, float]


def noisy_bearing(beta: Vec3, noise: Vec3, sigma_rad: float) -> Vec3:
    """A unit bearing tilted by angular noise: ``sigma noise`` (``noise`` standard normal per
    axis) projected onto the bearing's tangent plane, added, renormalized. The one camera-noise
    model of the project (the simulator's camera, both engines of the headless runner)."""
    n0, n1, n2 = noise[0] * sigma_rad, noise[1] * sigma_rad, noise[2] * sigma_rad
    nb = n0 * beta[0] + n1 * beta[1] + n2 * beta[2]
    o0 = beta[0] + (n0 - nb * beta[0])
    o1 = beta[1] + (n1 - nb * beta[1])
    o2 = beta[2] + (n2 - nb * beta[2])
    norm = math.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
    return (o0 / norm, o1 / norm, o2 / norm)


def noisy_bearings(beta: FloatArray, noise: FloatArray, sigma_rad: float) -> FloatArray:
    """:func:`noisy_bearing` of every row of ``beta`` ``(E, 3)`` with ``noise`` ``(E, 3)``."""
    b, z = beta.tolist(), noise.tolist()
    out = [
        noisy_bearing((r[0], r[1], r[2]), (q[0], q[1], q[2]), sigma_rad)
        for r, q in zip(b, z, strict=True)
    ]
    return np.asarray(out, dtype=float).reshape(beta.shape)


def perturb_bearings(
    beta: FloatArray, noise_std_rad: float, dropout: float, rng: np.random.Generator
) -> tuple[np.ndarray, FloatArray]:
    """Noisy unit bearings and a keep-mask: each bearing is tilted by a Gaussian vector in its
    tangent plane (std ``noise_std_rad`` per axis) and renormalized; each is dropped with
    probability ``dropout``. Returns ``(keep (E,) bool, beta_noisy (E, 3))``."""
    e = beta.shape[0]
    keep = rng.random(e) >= dropout if dropout > 0.0 else np.ones(e, dtype=bool)
    if noise_std_rad == 0.0 or e == 0:
        return keep, beta.copy()
    return keep, noisy_bearings(beta, rng.standard_normal((e, 3)), noise_std_rad)


class CameraPublisher:
    """Tick hook: publishes every vehicle's bearings and truth at the camera rate."""

    def __init__(
        self,
        config: CameraConfig,
        fleet: str,
        put: Callable[[str, bytes], None],
        ids: list[int] | None = None,
        publish_truth: bool = True,
    ) -> None:
        self.config = config
        self.fleet = fleet
        self.put = put
        self.ids = ids
        self.publish_truth = publish_truth
        self.rng = np.random.default_rng(config.seed)
        self.next_t_s: FloatArray | None = None
        """Each vehicle's next frame time (set at the first tick, when the team is known)."""
        self.seqs: list[int] = []
        self.published = 0

    @property
    def seq(self) -> int:
        """Frames published so far by the camera that published most."""
        return max(self.seqs, default=0)

    def __call__(self, t_s: float, world: World) -> None:
        period = 1.0 / self.config.rate_hz
        if self.next_t_s is None:
            self.seqs = [0] * world.n
            self.next_t_s = np.zeros(world.n)
            if self.config.unsynchronized:
                phase = np.random.default_rng([self.config.seed, 71]).uniform(0.0, period, world.n)
                self.next_t_s = t_s + phase
        due = t_s + 1e-9 >= self.next_t_s
        if not due.any():
            return
        self.next_t_s[due] = np.maximum(self.next_t_s[due] + period, t_s)
        for key, payload in self.frame(t_s, world, due):
            self.put(key, encode(payload))
            self.published += 1
        for i in np.flatnonzero(due):
            self.seqs[i] += 1

    def frame(
        self, t_s: float, world: World, due: np.ndarray | None = None
    ) -> list[tuple[str, CameraBearings | Truth]]:
        """The payloads of one camera frame at time ``t_s`` (key, payload) of every vehicle,
        or of the vehicles where ``due`` (bool ``(N,)``) is set."""
        cfg = self.config
        ids = self.ids if self.ids is not None else list(range(world.n))
        seqs = self.seqs or [0] * world.n
        edges, beta, _ = visible_bearings(world.p_ned, world.yaw_rad, cfg.fov_deg, cfg.range_m)
        keep, beta = perturb_bearings(beta, cfg.noise_std_rad, cfg.dropout, self.rng)
        edges, beta = edges[keep], beta[keep]
        out: list[tuple[str, CameraBearings | Truth]] = []
        for i in range(world.n):
            if due is not None and not due[i]:
                continue
            rows = edges[:, 0] == i
            out.append(
                (
                    camera_key(self.fleet, ids[i]),
                    CameraBearings(
                        sender=ids[i],
                        seq=seqs[i],
                        stamp_s=t_s,
                        targets=[ids[j] for j in edges[rows, 1]],
                        beta_body=[tuple(b) for b in beta[rows].tolist()],
                    ),
                )
            )
            if self.publish_truth:
                out.append(
                    (
                        truth_key(self.fleet, ids[i]),
                        Truth(
                            sender=ids[i],
                            seq=seqs[i],
                            stamp_s=t_s,
                            p_ned=tuple(world.p_ned[i].tolist()),
                            v_ned=tuple(world.v_ned[i].tolist()),
                            yaw_rad=float(world.yaw_rad[i]),
                            yaw_rate_rad_s=float(world.yaw_rate_rad_s[i]),
                        ),
                    )
                )
        return out

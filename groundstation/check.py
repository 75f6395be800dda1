"""Rigidity analysis of a formation: the report behind ``bearingflock check``.

For one formation (poses, cameras, sensing edges) it answers the questions an operator asks
before flying: can the team localize itself from bearings (infinitesimal bearing rigidity in
R^3 x S^1, paper 000 eq. 3-5, and in SE(3), paper 001 eq. 22), does angle rigidity agree
(paper 003), how far is it from flexible (rigidity eigenvalues), does motion make the metric
scale observable (dynamic observability matrix, paper 001 sec. III), which agents are weak
points, and which single edge losses would break rigidity.
"""

from __future__ import annotations

import msgspec
import numpy as np

from messages.formation import Formation
from onboard.geometry import FloatArray, IntArray, bearings_world, rot_z
from onboard.graph import angle_set, formation_edges, in_degree, out_degree, reciprocal_pairs
from onboard.rigidity.angle import (
    angle_rigidity_eigenvalue,
    angle_rigidity_rank,
    expected_angle_rank,
    weighted_angle_rigidity_eigenvalue,
)
from onboard.rigidity.bearing import ibr_r3s1, ibr_se3
from onboard.rigidity.observability import dbom_fields_rank, r3s1_observability_report
from onboard.rigidity.weights import SensingModel

VELOCITY_SEED = 0
"""Seed of the generic body velocities used when the file gives none."""

COLLINEAR_TOLERANCE = 1e-6
"""A vertex whose measured bearings span a cone narrower than this (|sin|) sees one line only."""


class AgentRow(msgspec.Struct):
    id: int
    position_ned: list[float]
    yaw_deg: float
    fov_deg: float
    range_m: float
    out_degree: int
    in_degree: int


class DegenerateVertex(msgspec.Struct):
    id: int
    reason: str


class CheckReport(msgspec.Struct):
    """Everything ``bearingflock check`` prints; ``--json`` emits exactly these fields."""

    name: str
    n_agents: int
    n_edges: int
    edge_source: str
    edges: list[tuple[int, int]]
    reciprocal_pairs: list[tuple[int, int]]
    agents: list[AgentRow]
    ibr_r3s1: bool
    rank_r3s1: int
    expected_rank_r3s1: int
    rigidity_eigenvalue_bearing: float
    ibr_se3: bool
    rank_se3: int
    expected_rank_se3: int
    rigidity_eigenvalue_se3: float
    iar: bool
    rank_angle: int
    expected_rank_angle: int
    rigidity_eigenvalue_angle: float
    rigidity_eigenvalue_angle_weighted: float | None
    paper003_theorem_holds: bool
    scale_observable_moving: bool
    rank_observability_static: int
    rank_observability_moving: int
    expected_rank_observability_moving: int
    rank_dbom_fields: int
    """Rank of paper 001's DBOM with one row block per input vector field (eq. 13c, 16), at the
    file's poses with level attitudes; independent of the velocities (``onboard/rigidity/
    observability.py:dbom_fields_matrix``). The ``rank_observability_*`` keys differentiate the
    one motion in ``velocities`` instead."""
    expected_rank_dbom_fields: int
    velocities: str
    degenerate_vertices: list[DegenerateVertex]
    critical_edges: list[tuple[int, int]]
    notes: list[str]


def _ids(formation: Formation, edges: IntArray) -> list[tuple[int, int]]:
    return formation.id_pairs(edges)


def _angle_rigidity(p_ned: FloatArray, edges: IntArray) -> tuple[bool, int, int, float]:
    """IAR verdict, rank, expected rank and unweighted eigenvalue (paper 003; needs N >= 3)."""
    n = len(p_ned)
    if n < 3 or len(edges) == 0:
        return False, 0, max(3 * n - 7, 0), 0.0
    expected = expected_angle_rank(n, 3)
    angles = angle_set(edges)
    if len(angles) == 0:
        return False, 0, expected, 0.0
    rank = angle_rigidity_rank(p_ned, edges)
    return rank == expected, rank, expected, angle_rigidity_eigenvalue(p_ned, angles)


def _degenerate_vertices(formation: Formation, edges: IntArray) -> list[DegenerateVertex]:
    """Agents that weaken the framework: too few bearings, collinear bearings, unseen."""
    n = formation.n
    out_deg = out_degree(edges, n)
    in_deg = in_degree(edges, n)
    b, _ = bearings_world(formation.p_ned, edges) if len(edges) else (np.zeros((0, 3)), None)
    found: list[DegenerateVertex] = []
    for v in range(n):
        agent_id = int(formation.ids[v])
        if out_deg[v] == 0 and in_deg[v] == 0:
            found.append(DegenerateVertex(agent_id, "isolated: sees no one and no one sees it"))
            continue
        if out_deg[v] < 2:
            found.append(
                DegenerateVertex(
                    agent_id,
                    f"measures {out_deg[v]} bearing(s); angle rigidity needs at least 2 (paper 003)",
                )
            )
        else:
            mine = b[edges[:, 0] == v]
            cross = np.linalg.norm(np.cross(mine[:, None, :], mine[None, :, :]), axis=-1)
            if cross.max() < COLLINEAR_TOLERANCE:
                found.append(DegenerateVertex(agent_id, "all its bearings lie on one line"))
        if in_deg[v] == 0:
            found.append(DegenerateVertex(agent_id, "no agent sees it"))
    return found


def _critical_edges(formation: Formation, edges: IntArray) -> list[tuple[int, int]]:
    """Edges whose loss alone breaks IBR in R^3 x S^1 (empty when the graph is not IBR)."""
    critical = []
    for k in range(len(edges)):
        rest = np.delete(edges, k, axis=0)
        if len(rest) == 0 or not ibr_r3s1(formation.p_ned, formation.yaw_rad, rest).is_rigid:
            critical.append(k)
    return _ids(formation, edges[critical]) if critical else []


def _weighted_eigenvalue(formation: Formation, edges: IntArray) -> float | None:
    """Weighted angle eigenvalue with the field-of-view and range model, if one model fits all."""
    if formation.edge_source != "camera" or formation.n < 3:
        return None
    if np.ptp(formation.fov_deg) > 0 or np.ptp(formation.range_m) > 0:
        return None
    model = SensingModel(fov_deg=float(formation.fov_deg[0]), range_m=float(formation.range_m[0]))
    lam, _ = weighted_angle_rigidity_eigenvalue(formation.p_ned, formation.yaw_rad, edges, model)
    return max(float(lam), 0.0)


def analyze(formation: Formation) -> CheckReport:
    """Run every rigidity and observability test on a formation."""
    edges = formation_edges(formation)
    n = formation.n
    notes: list[str] = []
    p, yaw = formation.p_ned, formation.yaw_rad
    if len(edges):
        r3s1 = ibr_r3s1(p, yaw, edges)
        se3 = ibr_se3(p, rot_z(yaw), edges)
        r3s1_rank, r3s1_rigid, r3s1_eig = r3s1.rank, r3s1.is_rigid, r3s1.eigenvalue
        se3_rank, se3_rigid, se3_eig = se3.rank, se3.is_rigid, se3.eigenvalue
    else:
        notes.append("the sensing graph has no edges")
        r3s1_rank, r3s1_rigid, r3s1_eig = 0, False, 0.0
        se3_rank, se3_rigid, se3_eig = 0, False, 0.0
    iar, rank_angle, expected_angle, eig_angle = _angle_rigidity(p, edges)
    min_out = int(out_degree(edges, n).min()) if n else 0
    if formation.velocity_body is not None:
        u_body, velocities = formation.velocity_body, "from the file"
    else:
        u_body = np.random.default_rng(VELOCITY_SEED).normal(size=(n, 3))
        velocities = f"generic (normal, seed {VELOCITY_SEED})"
    if len(edges):
        obs = r3s1_observability_report(p, yaw, u_body, edges)
        obs_static, obs_moving = obs.static_rank, obs.dynamic_rank
        obs_expected, observable = obs.expected_dynamic_rank, obs.scale_observable
        rank_fields = dbom_fields_rank(p, rot_z(yaw), edges)
    else:
        rank_fields = 0
        obs_static = obs_moving = 0
        obs_expected, observable = 4 * n - 4, False
    pairs = reciprocal_pairs(edges)
    if len(pairs) == 0:
        notes.append(
            "no reciprocal pair: relative yaw and the SfM scale observers of paper 000 need "
            "at least one pair of agents that see each other"
        )
    return CheckReport(
        name=formation.name,
        n_agents=n,
        n_edges=len(edges),
        edge_source=formation.edge_source,
        edges=_ids(formation, edges),
        reciprocal_pairs=_ids(formation, pairs),
        agents=[
            AgentRow(
                id=int(formation.ids[v]),
                position_ned=[float(x) for x in p[v]],
                yaw_deg=float(np.rad2deg(yaw[v])),
                fov_deg=float(formation.fov_deg[v]),
                range_m=float(formation.range_m[v]),
                out_degree=int(out_degree(edges, n)[v]),
                in_degree=int(in_degree(edges, n)[v]),
            )
            for v in range(n)
        ],
        ibr_r3s1=r3s1_rigid,
        rank_r3s1=r3s1_rank,
        expected_rank_r3s1=4 * n - 5,
        rigidity_eigenvalue_bearing=float(r3s1_eig),
        ibr_se3=se3_rigid,
        rank_se3=se3_rank,
        expected_rank_se3=6 * n - 7,
        rigidity_eigenvalue_se3=float(se3_eig),
        iar=iar,
        rank_angle=rank_angle,
        expected_rank_angle=expected_angle,
        rigidity_eigenvalue_angle=float(eig_angle),
        rigidity_eigenvalue_angle_weighted=_weighted_eigenvalue(formation, edges),
        paper003_theorem_holds=se3_rigid == (iar and min_out >= 2),
        scale_observable_moving=observable,
        rank_observability_static=obs_static,
        rank_observability_moving=obs_moving,
        expected_rank_observability_moving=obs_expected,
        rank_dbom_fields=rank_fields,
        expected_rank_dbom_fields=6 * n - 6,
        velocities=velocities,
        degenerate_vertices=_degenerate_vertices(formation, edges),
        critical_edges=_critical_edges(formation, edges) if r3s1_rigid else [],
        notes=notes,
    )

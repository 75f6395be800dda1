"""Directed sensing graphs: edge lists, reciprocal pairs, angle sets, field-of-view sensing.

Vertices are indices ``0..N-1``; an edge ``(i, j)`` means vertex ``i`` measures the bearing to
``j``. Edge lists are ``(E, 2)`` int arrays, sorted and without self loops or duplicates
(:func:`normalize_edges`). Every function is pure.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from messages.formation import Formation
from onboard.geometry import FloatArray, IntArray, bearings_world, camera_axis_ned


def normalize_edges(edges: ArrayLike) -> IntArray:
    """Return ``edges`` as a sorted ``(E, 2)`` int64 array without duplicates or self loops."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    e = e[e[:, 0] != e[:, 1]]
    return np.unique(e, axis=0) if len(e) else e


def complete_graph(n: int) -> IntArray:
    """Every vertex sees every other one: ``N (N - 1)`` directed edges."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    mask = i != j
    return np.stack([i[mask], j[mask]], axis=1).astype(np.int64)


def reciprocal_pairs(edges: ArrayLike) -> IntArray:
    """Reciprocal subgraph ``E_u = {(i, j): (i, j) in E, (j, i) in E, i < j}`` as ``(K, 2)``."""
    e = normalize_edges(edges)
    fwd = {(int(a), int(b)) for a, b in e}
    pairs = sorted((a, b) for a, b in fwd if a < b and (b, a) in fwd)
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def reciprocal_components(edges: ArrayLike, n: int) -> list[list[int]]:
    """Connected components of ``0..N-1`` under the reciprocal pairs (:func:`reciprocal_pairs`),
    each sorted, in order of their smallest vertex. Relative yaws come from reciprocal pairs
    only (paper 002 fig. 6), so the team's yaws are tied together exactly when this is one
    component (paper 002: "a spanning tree of the formation control graph")."""
    parent = list(range(n))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in reciprocal_pairs(edges).tolist():
        if 0 <= a < n and 0 <= b < n:
            parent[root(a)] = root(b)
    comps: dict[int, list[int]] = {}
    for v in range(n):
        comps.setdefault(root(v), []).append(v)
    return sorted(comps.values())


def edge_index(edges: ArrayLike) -> dict[tuple[int, int], int]:
    """Map ``(i, j) -> row`` of an edge list."""
    return {(int(a), int(b)): k for k, (a, b) in enumerate(np.asarray(edges).reshape(-1, 2))}


def angle_set_with_rows(edges: ArrayLike) -> tuple[IntArray, IntArray, IntArray]:
    """Angle set of paper 003 with, per angle, the rows of ``(i, j)`` and ``(i, k)`` in ``edges``.

    The angle set is ``{(i, j, k): (i, j) in E, (i, k) in E, j < k}``: each angle is measured at
    ``i`` between its bearings to ``j`` and ``k``. ``edges`` must be normalized
    (:func:`normalize_edges`: sorted, unique). No Python loop: an edge at position ``q`` among
    the ``m`` out-edges of its tail pairs with the ``m - 1 - q`` out-edges after it.
    """
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if len(e) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return np.zeros((0, 3), dtype=np.int64), empty, empty
    tails = e[:, 0]
    counts = np.bincount(tails)
    first = np.cumsum(counts) - counts
    position = np.arange(len(e)) - first[tails]
    partners = counts[tails] - 1 - position
    rows_ij = np.repeat(np.arange(len(e)), partners)
    block_start = np.repeat(np.cumsum(partners) - partners, partners)
    rows_ik = rows_ij + 1 + (np.arange(len(rows_ij)) - block_start)
    angles = np.stack([tails[rows_ij], e[rows_ij, 1], e[rows_ik, 1]], axis=1)
    return angles.astype(np.int64), rows_ij, rows_ik


def angle_set(edges: ArrayLike) -> IntArray:
    """Angle set ``(A, 3)`` of a directed graph (see :func:`angle_set_with_rows`)."""
    return angle_set_with_rows(normalize_edges(edges))[0]


def out_degree(edges: ArrayLike, n: int) -> IntArray:
    """Number of bearings each vertex measures."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    return np.bincount(e[:, 0], minlength=n).astype(np.int64)


def in_degree(edges: ArrayLike, n: int) -> IntArray:
    """Number of vertices that measure a bearing to each vertex."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    return np.bincount(e[:, 1], minlength=n).astype(np.int64)


def sensing_graph(
    p_ned: ArrayLike,
    yaw_rad: ArrayLike,
    fov_deg: ArrayLike,
    range_m: ArrayLike,
) -> IntArray:
    """Directed edges ``(i, j)`` with ``j`` inside ``i``'s camera cone and range.

    The camera axis is body x of a level vehicle, ``c_i = R_z(psi_i) e1``; ``j`` is seen when
    ``c_i . b_ij >= cos(fov_i / 2)`` and ``d_ij <= range_i``. ``fov_deg`` and ``range_m`` are
    scalars or per-vertex arrays; a field of view of 360 degrees or more sees all around.
    """
    p = np.asarray(p_ned, dtype=float)
    n = len(p)
    candidates = complete_graph(n)
    if n < 2:
        return candidates
    b, d = bearings_world(p, candidates)
    fov = np.broadcast_to(np.asarray(fov_deg, dtype=float), (n,))
    rng = np.broadcast_to(np.asarray(range_m, dtype=float), (n,))
    axis: FloatArray = camera_axis_ned(np.broadcast_to(np.asarray(yaw_rad, dtype=float), (n,)))
    i = candidates[:, 0]
    cos_half = np.cos(np.deg2rad(np.minimum(fov[i], 360.0)) / 2.0)
    in_cone = (np.sum(axis[i] * b, axis=1) >= cos_half) | (fov[i] >= 360.0)
    return candidates[in_cone & (d <= rng[i])]


def formation_edges(formation: Formation) -> IntArray:
    """Sensing edges of a formation file: its ``[[edge]]`` list, else its cameras' field of view
    and range, else the complete graph (the rule documented in :mod:`messages.formation`)."""
    if formation.edge_source == "file" and formation.edges_file is not None:
        return normalize_edges(formation.edges_file)
    if formation.edge_source == "camera":
        return sensing_graph(
            formation.p_ned, formation.yaw_rad, formation.fov_deg, formation.range_m
        )
    return complete_graph(formation.n)

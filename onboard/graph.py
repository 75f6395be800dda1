"""Directed sensing graphs: edge lists, reciprocal pairs, angle sets, field-of-view sensing.

Vertices are indices ``0..N-1``; an edge ``(i, j)`` means vertex ``i`` measures the bearing to
``j``. Edge lists are ``(E, 2)`` int arrays, sorted and without self loops or duplicates
(:func:`normalize_edges`). Every function is pure.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

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


def edge_index(edges: ArrayLike) -> dict[tuple[int, int], int]:
    """Map ``(i, j) -> row`` of an edge list."""
    return {(int(a), int(b)): k for k, (a, b) in enumerate(np.asarray(edges).reshape(-1, 2))}


def angle_set(edges: ArrayLike) -> IntArray:
    """Angle set of paper 003: ``{(i, j, k): (i, j) in E, (i, k) in E, j < k}`` as ``(A, 3)``.

    Each angle is measured at ``i`` between its bearings to ``j`` and ``k``.
    """
    e = normalize_edges(edges)
    if len(e) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    out = []
    for i in np.unique(e[:, 0]):
        nbrs = e[e[:, 0] == i, 1]
        jj, kk = np.triu_indices(len(nbrs), k=1)
        out.append(np.stack([np.full(len(jj), i), nbrs[jj], nbrs[kk]], axis=1))
    return np.concatenate(out).astype(np.int64) if out else np.zeros((0, 3), dtype=np.int64)


def angle_edge_rows(edges: ArrayLike, angles: ArrayLike) -> tuple[IntArray, IntArray]:
    """Rows of edges ``(i, j)`` and ``(i, k)`` in ``edges`` for every angle ``(i, j, k)``."""
    idx = edge_index(edges)
    a = np.asarray(angles, dtype=np.int64).reshape(-1, 3)
    rows_ij = np.array([idx[(int(i), int(j))] for i, j, _ in a], dtype=np.int64)
    rows_ik = np.array([idx[(int(i), int(k))] for i, _, k in a], dtype=np.int64)
    return rows_ij, rows_ik


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

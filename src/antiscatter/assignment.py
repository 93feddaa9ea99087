"""Gated, sparse, optimal one-to-one assignment of points to points.

Used to match detections to truth (evaluation) and to tracks (tracking).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["match", "gates"]


def gates(truth_radii: np.ndarray, *, min_gate: float = 2.0, scale: float = 1.0) -> np.ndarray:
    """Largest centre distance (pixels) at which a detection counts for each truth particle:
    ``max(scale * radius, min_gate)``."""
    return np.maximum(scale * np.asarray(truth_radii, dtype=np.float64), min_gate)


def match(truth_centres: np.ndarray, truth_gates: np.ndarray,
          det_centres: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Optimal one-to-one assignment on centre distance, gated per truth particle.

    Only pairs closer than the truth particle's gate may match; among those the
    assignment maximises the number of matches, then minimises the summed
    distance.  The problem is split into the connected groups of candidate
    pairs (sparse, via a k-d tree), each solved exactly with SciPy's
    ``linear_sum_assignment``, so hundreds of particles cost little.

    Parameters
    ----------
    truth_centres : (T, 2) pixels.
    truth_gates : (T,) maximum matching distance per truth particle, pixels.
    det_centres : (D, 2) pixels.

    Returns
    -------
    matches : (K, 2) int array of (truth index, detection index).
    unmatched_truth : (T - K,) int array.
    unmatched_dets : (D - K,) int array.
    """
    truth_centres = np.asarray(truth_centres, dtype=np.float64).reshape(-1, 2)
    det_centres = np.asarray(det_centres, dtype=np.float64).reshape(-1, 2)
    nt, nd = len(truth_centres), len(det_centres)
    if nt == 0 or nd == 0:
        return np.empty((0, 2), np.int64), np.arange(nt), np.arange(nd)
    tree = cKDTree(det_centres)
    candidates = tree.query_ball_point(truth_centres, r=np.asarray(truth_gates, dtype=np.float64))
    rows = np.fromiter((t for t, ds in enumerate(candidates) for _ in ds), np.int64)
    cols = np.fromiter((d for ds in candidates for d in ds), np.int64)
    if len(rows) == 0:
        return np.empty((0, 2), np.int64), np.arange(nt), np.arange(nd)
    dist = np.hypot(*(truth_centres[rows] - det_centres[cols]).T)
    graph = coo_matrix((np.ones(len(rows)), (rows, nt + cols)), shape=(nt + nd, nt + nd))
    _, component = connected_components(graph, directed=False)
    edge_component = component[rows]
    order = np.argsort(edge_component, kind="stable")
    bounds = np.flatnonzero(np.diff(edge_component[order])) + 1
    pairs = []
    for group in np.split(order, bounds):
        r, c, d = rows[group], cols[group], dist[group]
        if len(group) == 1:
            pairs.append((r[0], c[0]))
            continue
        ut, ti = np.unique(r, return_inverse=True)
        ud, di = np.unique(c, return_inverse=True)
        big = d.sum() + 1.0  # any infeasible pair costs more than all feasible ones
        cost = np.full((len(ut), len(ud)), big)
        cost[ti, di] = d
        a, b = linear_sum_assignment(cost)
        feasible = cost[a, b] < big
        pairs.extend(zip(ut[a[feasible]], ud[b[feasible]]))
    matches = np.array(sorted(pairs), np.int64).reshape(-1, 2)
    unmatched_truth = np.setdiff1d(np.arange(nt), matches[:, 0])
    unmatched_dets = np.setdiff1d(np.arange(nd), matches[:, 1])
    return matches, unmatched_truth, unmatched_dets

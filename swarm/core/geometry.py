"""Pairs of points closer than a distance: the one neighbour search the referee, the recorder and the
world's checks share (pure numpy: no zenoh, no compiler)."""

from __future__ import annotations

import numpy as np

DENSE_N = 256  # pairwise distances over every pair up to this many robots, sort-and-sweep above


def pairs_within(x: np.ndarray, y: np.ndarray, within: float,
                 upper: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Index pairs i < j of points (x, y) [m] closer than `within` [m], and their distances [m].

    upper: np.triu_indices(len(x), 1), when the caller keeps it (saves its construction per call)."""
    n = len(x)
    if n < 2:
        e = np.zeros(0, np.int64)
        return e, e, np.zeros(0)
    if n <= DENSE_N:
        i, j = upper if upper is not None else np.triu_indices(n, 1)
        dx, dy = x[i] - x[j], y[i] - y[j]
        d2 = dx * dx + dy * dy
        hit = np.flatnonzero(d2 < within * within)
        return i[hit], j[hit], np.sqrt(d2[hit])
    order = np.argsort(x, kind="stable")
    sx, sy = x[order], y[order]
    ii, jj, dd = [], [], []
    for k in range(1, n):
        dx = sx[k:] - sx[:-k]
        near = np.flatnonzero(dx < within)
        if not near.size:
            break
        d = np.hypot(dx[near], sy[k:][near] - sy[:-k][near])
        hit = near[d < within]
        a, b = order[hit], order[hit + k]
        ii.append(np.minimum(a, b)), jj.append(np.maximum(a, b)), dd.append(d[d < within])
    if not ii:
        e = np.zeros(0, np.int64)
        return e, e, np.zeros(0)
    return np.concatenate(ii), np.concatenate(jj), np.concatenate(dd)

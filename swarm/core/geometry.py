"""Pairs of points closer than a distance (pure numpy: no zenoh, no compiler).

`pairs_within` is the neighbour search the referee, the recorder and the world's checks share (a
swarm's robots at one instant). `Grid`, `closest_pair` and `first_pair` serve the scenario checks and
generators, which must stay O(N) up to 10^5 robots and 10^6 obstacles whatever the input holds.
"""

from __future__ import annotations

import math

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
        ii.append(np.minimum(a, b))
        jj.append(np.maximum(a, b))
        dd.append(d[d < within])
    if not ii:
        e = np.zeros(0, np.int64)
        return e, e, np.zeros(0)
    return np.concatenate(ii), np.concatenate(jj), np.concatenate(dd)


# --------------------------------------------------------------------------- grid search
#
# The scenario checks need every pair closer than some distance among up to 10^5 robots (and 10^6
# obstacles): all pairs would be 5 * 10^9 distances. A uniform grid of square cells of side >= the
# distance puts every such pair in the 3 x 3 block of cells around either point, so the work is the
# number of points times the points in a block: O(N) while no cell is crowded (robots that keep a
# separation near the cell side hold at most a few a cell). Cells are found by sorting a hash of their
# (cx, cy) and binary search (O(N log N), no bounds needed, no Python loop per point); a bucket shared
# by two cells is harmless because candidates are kept only for their own cell.

CHUNK = 1 << 21  # candidate pairs handled at once: bounds the scratch memory (about 100 MB)
CROWD = 32  # closest_pair refines its cells while one holds more points than this
DENSE_CLOSEST = 64  # closest_pair compares every pair up to this many points


class Counter:
    """Counts the candidate pairs the searches examined (their work: tests hold it to O(N))."""

    def __init__(self) -> None:
        self.pairs = 0


def _cells(p: np.ndarray, side: float) -> np.ndarray:
    """(K, 2) int64 cell indices floor(p / side)."""
    return np.floor(p / side).astype(np.int64)


def _hash(c: np.ndarray) -> np.ndarray:
    """A 64-bit hash of (cx, cy) rows (wrapping products, as in swarm.core.grid)."""
    return (c[:, 0] * np.int64(73856093)) ^ (c[:, 1] * np.int64(19349663))


def _usable_side(side: float, *arrays: np.ndarray) -> float:
    """`side`, raised if needed so that every |coordinate| / side stays below 2^50 (exact int64 cells)."""
    top = max((float(np.max(np.abs(a))) for a in arrays if len(a)), default=0.0)
    return max(side, top * 2.0**-50, 1e-300)


class Grid:
    """(L, 2) points [m] in square cells of side >= `side` [m], for repeated searches of pairs within it."""

    def __init__(self, points: np.ndarray, side: float):
        self.points = np.asarray(points, float).reshape(-1, 2)
        self.side = _usable_side(side, self.points)
        self.cells = _cells(self.points, self.side)
        h = _hash(self.cells)
        self.order = np.argsort(h, kind="stable")
        self.sorted_hash = h[self.order]

    def pairs(self, a: np.ndarray, within: float, counter: Counter | None = None,
              same: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pairs (i, j) of a point a[i] and a grid point j at most `within` [m] apart, and their d2 [m^2].

        d2 = (a_i - b_j)_x^2 + (a_i - b_j)_y^2, computed exactly so (callers filter with their own strict
        or non-strict comparison). same: `a` is the grid's own points; then only i < j. Pairs come in
        no particular order. within must not exceed the cell side. The candidates examined are added to
        `counter`: the points of a times the grid's points in each one's 3 x 3 block of cells.
        """
        if not 0 <= within <= self.side:
            raise ValueError(f"within = {within!r} m must be in [0, the cell side {self.side!r} m]")
        a = np.asarray(a, float).reshape(-1, 2)
        b, cb = self.points, self.cells
        empty = np.zeros(0, np.int64)
        if len(a) == 0 or len(b) == 0:
            return empty, empty, np.zeros(0)
        if float(np.max(np.abs(a))) * 2.0**-50 > self.side:
            raise ValueError("query points too far out for the grid's cells")
        ca = _cells(a, self.side)
        w2 = within * within
        out_i, out_j, out_d = [], [], []
        for ox in (-1, 0, 1):
            for oy in (-1, 0, 1):
                q = ca + np.array([ox, oy], np.int64)
                hq = _hash(q)
                lo = np.searchsorted(self.sorted_hash, hq, "left")
                counts = np.searchsorted(self.sorted_hash, hq, "right") - lo
                rows_all = np.flatnonzero(counts)
                if not rows_all.size:
                    continue
                ends = np.cumsum(counts[rows_all])
                start = 0
                while start < len(rows_all):
                    # the next queries whose candidates fit in one chunk (at least one query)
                    base = int(ends[start - 1]) if start else 0
                    stop = max(start + 1, int(np.searchsorted(ends, base + CHUNK, "right")))
                    rows = rows_all[start:stop]
                    cnt = counts[rows]
                    total = int(ends[stop - 1]) - base
                    if counter is not None:
                        counter.pairs += total
                    ii = np.repeat(rows, cnt)
                    jj = self.order[np.repeat(lo[rows] - (np.cumsum(cnt) - cnt), cnt) + np.arange(total)]
                    keep = (cb[jj, 0] == q[ii, 0]) & (cb[jj, 1] == q[ii, 1])
                    if same:
                        keep &= ii < jj
                    ii, jj = ii[keep], jj[keep]
                    dx = a[ii, 0] - b[jj, 0]
                    dy = a[ii, 1] - b[jj, 1]
                    d2 = dx * dx + dy * dy
                    hit = d2 <= w2
                    out_i.append(ii[hit])
                    out_j.append(jj[hit])
                    out_d.append(d2[hit])
                    start = stop
        if not out_i:
            return empty, empty, np.zeros(0)
        return np.concatenate(out_i), np.concatenate(out_j), np.concatenate(out_d)


def first_pair(i: np.ndarray, j: np.ndarray, d2: np.ndarray) -> tuple[int, int, float]:
    """Of non-empty pairs, the one of smallest d2, ties to the smallest i, then the smallest j: (i, j, d2)."""
    k = int(np.lexsort((j, i, d2))[0])
    return int(i[k]), int(j[k]), float(d2[k])


def closest_pair(points: np.ndarray, within: float, counter: Counter | None = None) -> tuple[int, int, float] | None:
    """The closest pair i < j of (K, 2) points [m] if at most `within` [m] apart: (i, j, d [m]), else None.

    Ties go to the smallest i, then the smallest j (the pair an all-pairs search in index order finds).
    O(K log K) whatever the points: coincident points are found by sorting; a cell crowded with more
    than CROWD points (points much closer than `within`) shrinks the cells to the closest distance
    among its points, a bound on the answer, until no cell is crowded, so no search runs over all pairs.
    """
    p = np.asarray(points, float).reshape(-1, 2)
    if len(p) < 2 or not within >= 0:
        return None
    if len(p) <= DENSE_CLOSEST:  # a few points: every pair at once is quicker than any grid
        d2 = np.sum((p[:, None, :] - p[None, :, :]) ** 2, axis=2)
        d2[np.diag_indices(len(p))] = np.inf
        if counter is not None:
            counter.pairs += len(p) * (len(p) - 1) // 2
        i, j = divmod(int(np.argmin(d2)), len(p))  # row-major: the smallest i, then its smallest j (> i)
        d = math.sqrt(float(d2[i, j]))
        return (i, j, d) if d <= within else None
    twins = _coincident(p)
    if twins is not None:
        return twins[0], twins[1], 0.0
    side = within
    while True:
        grid = Grid(p, side)
        if grid.side > side:  # cells cannot get finer at these coordinates: search as they are
            break
        h = grid.sorted_hash
        starts = np.concatenate(([0], np.flatnonzero(h[1:] != h[:-1]) + 1))
        lengths = np.diff(np.concatenate((starts, [len(h)])))
        big = int(np.argmax(lengths))
        if lengths[big] <= CROWD:
            break
        members = grid.order[starts[big]:starts[big] + lengths[big]]
        members = members[(grid.cells[members] == grid.cells[members[0]]).all(axis=1)][:CROWD + 1]
        if len(members) <= CROWD:  # two cells sharing a hash bucket, not a crowded cell
            break
        sub = p[members]
        d2 = np.sum((sub[:, None, :] - sub[None, :, :]) ** 2, axis=2)
        d2[np.diag_indices(len(sub))] = np.inf
        if counter is not None:
            counter.pairs += len(sub) * (len(sub) - 1) // 2
        bound = math.sqrt(float(d2.min())) * (1.0 + 1e-12)  # an upper bound of the closest distance
        if not bound < side:
            break
        side = bound
    ii, jj, d2 = grid.pairs(p, min(side, grid.side), counter, same=True)
    if not len(ii):
        return None
    a, b, best = first_pair(ii, jj, d2)
    d = math.sqrt(best)
    return (a, b, d) if d <= within else None


def _coincident(p: np.ndarray) -> tuple[int, int] | None:
    """The first pair (smallest i, then smallest j > i) of points at exactly the same place, or None."""
    order = np.lexsort((np.arange(len(p)), p[:, 1], p[:, 0]))
    sp = p[order]
    same = (sp[1:, 0] == sp[:-1, 0]) & (sp[1:, 1] == sp[:-1, 1])
    if not same.any():
        return None
    # runs of equal points in `order`, ascending index within a run: the answer is the run whose first
    # index is smallest, paired with that run's second index
    starts = np.flatnonzero(np.concatenate(([True], ~same)))
    lengths = np.diff(np.concatenate((starts, [len(p)])))
    runs = starts[lengths > 1]
    best = runs[int(np.argmin(order[runs]))]
    return int(order[best]), int(order[best + 1])

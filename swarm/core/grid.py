"""Neighbour search on a uniform grid of square cells of side >= R (scalar style, see swarm.core.law).

Cells are (cx, cy) = (floor(x / side), floor(y / side)), the same cells as the zenoh key
space of docs/protocol.md. A spatial hash maps a cell to one of H buckets (H a power
of two >= 2 N), so the grid needs no bounds and costs O(N) to build whatever the
swarm's extent. Every body within `side` of a point lies in the 3x3 cells around the
point's cell. Bucket collisions are harmless: an entry is accepted only for its own
cell, so no body is visited twice.

A grid is three arrays: cells (n, 2) int64, head (H + 1) int64 (bucket b holds
order[head[b]:head[b + 1]]), order (n) int64 (ids in ascending order within a bucket).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from swarm.core.jit import Jit

_jit: Jit = globals().get("__swarm_jit__", lambda f: f)


def table_size(n: int) -> int:
    """Number of hash buckets for n bodies: a power of two >= 2 n (at least 16)."""
    h = 16
    while h < 2 * n:
        h *= 2
    return h


@_jit
def cell_index(v: float, side: float) -> int:
    return int(math.floor(v / side))


@_jit
def bucket(cx: int, cy: int, mask: int) -> int:
    return ((cx * 73856093) ^ (cy * 19349663)) & mask


@_jit
def build(xs: npt.NDArray[np.float64], ys: npt.NDArray[np.float64], n: int, side: float,
          cells: npt.NDArray[np.int64], head: npt.NDArray[np.int64], order: npt.NDArray[np.int64]) -> None:
    """Fill cells, head and order for the first n bodies at (xs, ys): a counting sort by bucket."""
    nb = head.shape[0] - 1
    mask = nb - 1
    for b in range(nb + 1):
        head[b] = 0
    for i in range(n):
        cx = cell_index(xs[i], side)
        cy = cell_index(ys[i], side)
        cells[i, 0] = cx
        cells[i, 1] = cy
        head[bucket(cx, cy, mask) + 1] += 1
    for b in range(1, nb + 1):
        head[b] += head[b - 1]
    for i in range(n):  # ascending i: ids stay sorted within a bucket
        b = bucket(cells[i, 0], cells[i, 1], mask)
        order[head[b]] = i
        head[b] += 1
    for b in range(nb - 1, 0, -1):  # head[b] now holds the start of b + 1: shift back
        head[b] = head[b - 1]
    head[0] = 0


@_jit
def near(x: float, y: float, side: float, xs: npt.NDArray[np.float64], ys: npt.NDArray[np.float64],
         cells: npt.NDArray[np.int64], head: npt.NDArray[np.int64], order: npt.NDArray[np.int64], radius: float,
         skip: int, out: npt.NDArray[np.int64]) -> int:
    """Write into `out` the ids of bodies closer than `radius` to (x, y), ascending; return the count.

    `skip` is an id to leave out (the querying robot), or -1. radius must be <= side.
    """
    mask = head.shape[0] - 2
    cx = cell_index(x, side)
    cy = cell_index(y, side)
    r2 = radius * radius
    n = 0
    for ddx in range(-1, 2):
        for ddy in range(-1, 2):
            ccx = cx + ddx
            ccy = cy + ddy
            b = bucket(ccx, ccy, mask)
            for idx in range(head[b], head[b + 1]):
                j = order[idx]
                if j == skip or cells[j, 0] != ccx or cells[j, 1] != ccy:
                    continue
                dx = x - xs[j]
                dy = y - ys[j]
                if dx * dx + dy * dy < r2:
                    out[n] = j
                    n += 1
    # insertion sort: a handful of ids
    for a in range(1, n):
        v = out[a]
        c = a - 1
        while c >= 0 and out[c] > v:
            out[c + 1] = out[c]
            c -= 1
        out[c + 1] = v
    return n

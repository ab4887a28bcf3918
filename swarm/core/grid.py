"""Neighbour search on a uniform grid of square cells of side >= R (scalar style, see swarm.core.law).

Cells are (cx, cy) = (floor(x / side), floor(y / side)), the same cells as the zenoh key
space of docs/protocol.md. A spatial hash maps a cell to one of H buckets (H a power
of two >= 2 N), so the grid needs no bounds and costs O(N) to build whatever the
swarm's extent. Every body within `side` of a point lies in the 3x3 cells around the
point's cell; the hash keeps the three cells of a row in consecutive buckets, so a
search reads three runs of the table. Bucket collisions are harmless: an entry is
accepted only in its own row's run and only for a cell of the 3x3, so no body is
counted twice.

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


# Cells of one row lie in consecutive buckets (cx + cy ROW_STRIDE mod H), so the three cells of a row around a
# point are one run of the table; the rows themselves are spread over it by the odd stride.
ROW_STRIDE = 2654435761


@_jit
def bucket(cx: int, cy: int, mask: int) -> int:
    return (cx + cy * ROW_STRIDE) & mask


@_jit
def build(xs: npt.NDArray[np.float64], ys: npt.NDArray[np.float64], n: int, side: float,
          cells: npt.NDArray[np.int64], head: npt.NDArray[np.int64], order: npt.NDArray[np.int64]) -> None:
    """Fill cells, head and order for the first n bodies at (xs, ys): a counting sort by bucket."""
    for i in range(n):
        cells[i, 0] = cell_index(xs[i], side)
        cells[i, 1] = cell_index(ys[i], side)
    _sort(n, cells, head, order)


@_jit
def update(xs: npt.NDArray[np.float64], ys: npt.NDArray[np.float64], n: int, side: float,
           cells: npt.NDArray[np.int64], head: npt.NDArray[np.int64], order: npt.NDArray[np.int64]) -> None:
    """build(), but the sort only when some body changed cell since the grid was last built for these n bodies
    (head and order are a function of the cells alone): at 1 mm a step, a body of a small swarm keeps its
    cell for thousands of steps."""
    changed = head[head.shape[0] - 1] != n
    for i in range(n):
        cx = cell_index(xs[i], side)
        cy = cell_index(ys[i], side)
        if cx != cells[i, 0] or cy != cells[i, 1]:
            cells[i, 0] = cx
            cells[i, 1] = cy
            changed = True
    if changed:
        _sort(n, cells, head, order)


@_jit
def _sort(n: int, cells: npt.NDArray[np.int64], head: npt.NDArray[np.int64], order: npt.NDArray[np.int64]) -> None:
    """head and order from the cells of the first n bodies: a counting sort by bucket, ids ascending within one."""
    nb = head.shape[0] - 1
    mask = nb - 1
    for b in range(nb + 1):
        head[b] = 0
    for i in range(n):
        head[bucket(cells[i, 0], cells[i, 1], mask) + 1] += 1
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
def _scan(lo: int, hi: int, x: float, y: float, cx: int, cy: int, r2: float, xs: npt.NDArray[np.float64],
          ys: npt.NDArray[np.float64], cells: npt.NDArray[np.int64], order: npt.NDArray[np.int64], skip: int,
          out: npt.NDArray[np.int64], n: int) -> int:
    """The bodies of order[lo:hi] in the cells (cx - 1 .. cx + 1, cy) and closer than sqrt(r2) to (x, y), but
    `skip`, appended to out[n:]; returns the new count. Without branches on the data: every entry is written,
    the count moves on a hit."""
    size = out.shape[0]
    for idx in range(lo, hi):
        j = order[idx]
        dx = x - xs[j]
        dy = y - ys[j]
        hit = (dx * dx + dy * dy < r2) & (cells[j, 1] == cy) & (abs(cells[j, 0] - cx) <= 1) & (j != skip)
        if n < size:
            out[n] = j
        n += int(hit)
    return n


@_jit
def near(x: float, y: float, side: float, xs: npt.NDArray[np.float64], ys: npt.NDArray[np.float64],
         cells: npt.NDArray[np.int64], head: npt.NDArray[np.int64], order: npt.NDArray[np.int64], radius: float,
         skip: int, out: npt.NDArray[np.int64]) -> int:
    """Write into `out` the ids of bodies closer than `radius` to (x, y), ascending; return the count.

    `skip` is an id to leave out (the querying robot), or -1. radius must be <= side.
    """
    nb = head.shape[0] - 1
    mask = nb - 1
    cx = cell_index(x, side)
    cy = cell_index(y, side)
    r2 = radius * radius
    n = 0
    for ddy in range(-1, 2):
        ccy = cy + ddy
        b0 = bucket(cx - 1, ccy, mask)
        if b0 + 3 <= nb:
            n = _scan(head[b0], head[b0 + 3], x, y, cx, ccy, r2, xs, ys, cells, order, skip, out, n)
        else:  # the row's run wraps around the table's end
            n = _scan(head[b0], head[nb], x, y, cx, ccy, r2, xs, ys, cells, order, skip, out, n)
            n = _scan(head[0], head[b0 + 3 - nb], x, y, cx, ccy, r2, xs, ys, cells, order, skip, out, n)
    # insertion sort: a handful of ids
    for a in range(1, n):
        v = out[a]
        c = a - 1
        while c >= 0 and out[c] > v:
            out[c + 1] = out[c]
            c -= 1
        out[c + 1] = v
    return n

"""Generators that stand where a scenario gives a list: formation patches, random starts,
rows of obstacles. Pure functions; randomness comes from the `rng` passed in.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Callable, cast

import numpy as np

from swarm.core.geometry import Counter, Grid
from swarm.core.errors import SwarmError

if TYPE_CHECKING:
    from collections.abc import Sequence


class GeneratorError(SwarmError, ValueError):
    """The generator cannot produce what was asked (e.g. no room for the robots)."""


def hex_patch(count: int, spacing: float) -> np.ndarray:
    """A centred hexagonal patch of `count` points, `spacing` [m] apart: (count, 2).

    Rows are horizontal; the patch grows ring by ring (1, 7, 19, 37, 61, 91, ... points
    fill whole rings). Within a ring points are ordered by angle from +x, so a count
    that is not a centred hexagonal number takes a contiguous arc of the outer ring.
    """
    if count < 1:
        raise GeneratorError(f"count must be >= 1, got {count}")
    rings = 0
    while 3 * rings * (rings + 1) + 1 < count:
        rings += 1
    # p = i a1 + j a2 with a1 = (spacing, 0), a2 = (spacing / 2, spacing sqrt(3) / 2), in plain floats
    # (the very products and sums, signed zeros included, of the numpy vectors this once used)
    a1x, a1y = float(spacing), 0.0
    a2x, a2y = 0.5 * spacing, 0.5 * math.sqrt(3.0) * spacing
    points = []
    for i in range(-rings, rings + 1):
        for j in range(-rings, rings + 1):
            ring = max(abs(i), abs(j), abs(i + j))
            if ring <= rings:
                px, py = i * a1x + j * a2x, i * a1y + j * a2y
                angle = math.atan2(py, px) % (2.0 * math.pi)
                points.append((ring, round(angle, 12), px, py))
    points.sort()
    out = np.array([[p[2], p[3]] for p in points[:count]])
    out[np.abs(out) < 1e-12] = 0.0
    return out


def obstacle_row(start: Sequence[float], end: Sequence[float], pitch: float) -> np.ndarray:
    """Centres of obstacles from `start` to `end` (both included), about `pitch` [m] apart: (K, 2)."""
    start_a, end_a = np.asarray(start, float), np.asarray(end, float)
    length = float(np.linalg.norm(end_a - start_a))
    if pitch <= 0:
        raise GeneratorError(f"pitch must be > 0, got {pitch}")
    intervals = max(1, int(round(length / pitch)))
    if length == 0.0:
        return start_a[None, :].copy()
    s = np.linspace(0.0, 1.0, intervals + 1)
    return cast(np.ndarray, start_a[None, :] + s[:, None] * (end_a - start_a)[None, :])


def random_poses(
    rng: np.random.Generator,
    count: int,
    region: tuple[float, float, float, float],
    min_separation: float,
    obstacles: np.ndarray,
    obstacle_clearance: float,
    max_tries: int = 200_000,
    progress: Callable[[str, int, int], None] | None = None,
    counter: Counter | None = None,
) -> np.ndarray:
    """`count` poses uniform in region (xmin, xmax, ymin, ymax), headings uniform in (-pi, pi].

    Positions are drawn one at a time and rejected when closer than min_separation [m]
    to a robot already placed or closer than obstacle_clearance [m] to an obstacle
    centre (obstacles: (M, >= 2) array). Returns (count, 3). Deterministic in `rng`.

    A draw is x = xmin + (xmax - xmin) u, then y likewise, u uniform in [0, 1): exactly what
    rng.uniform(xmin, xmax) computes, so the poses of a seed never change. Draws are taken from
    rng in batches (the obstacle test is vectorised over a batch) and the generator is set back
    to consume exactly the draws used: the headings and anything drawn after them stay as they
    were. Placed robots sit in a grid of cells of side min_separation, so a draw is tested against
    the robots of 3 x 3 cells (O(count) in all, counted in `counter`), not against every robot.
    progress(stage, done, total) is called every few thousand draws.
    """
    xmin, xmax, ymin, ymax = region
    if not (xmax > xmin and ymax > ymin):
        raise GeneratorError(f"region {list(region)} is empty (need xmin < xmax and ymin < ymax)")
    placed = np.empty((count, 2))
    n = 0
    tries = 0
    centres = np.asarray(obstacles, float)[:, :2] if len(obstacles) else np.empty((0, 2))
    clearance = float(obstacle_clearance)
    near_obstacles = Grid(centres, clearance) if len(centres) and clearance > 0 else None
    sep = float(min_separation)
    sep2 = sep**2
    cells: dict[tuple[int, int], list[tuple[float, float]]] = {}
    x0, xr, y0, yr = float(xmin), float(xmax) - float(xmin), float(ymin), float(ymax) - float(ymin)
    examined = 0
    while n < count:
        if tries >= max_tries:
            raise GeneratorError(
                f"placed only {n} of {count} robots in region {list(region)} with min_separation "
                f"{min_separation} m after {max_tries} draws: make the region larger"
            )
        batch = min(max(64, 2 * (count - n)), 4096, max_tries - tries)
        state = rng.bit_generator.state
        u = rng.random(2 * batch)
        xs = x0 + xr * u[0::2]
        ys = y0 + yr * u[1::2]
        blocked = np.zeros(batch, bool)
        if near_obstacles is not None:
            i, _, d2 = near_obstacles.pairs(np.column_stack([xs, ys]), clearance, counter)
            blocked[i[d2 < clearance**2]] = True
        used = 0
        for x, y, no in zip(xs.tolist(), ys.tolist(), blocked.tolist()):
            used += 1
            if no:
                continue
            if sep2 > 0.0:
                cx, cy = math.floor(x / sep), math.floor(y / sep)
                clash = False
                for gx in (cx - 1, cx, cx + 1):
                    for gy in (cy - 1, cy, cy + 1):
                        for px, py in cells.get((gx, gy), ()):
                            examined += 1
                            dx, dy = px - x, py - y
                            if dx * dx + dy * dy < sep2:
                                clash = True
                if clash:
                    continue
                cells.setdefault((cx, cy), []).append((x, y))
            placed[n] = (x, y)
            n += 1
            if n == count:
                break
        tries += used
        if used < batch:  # give back the draws not used
            rng.bit_generator.state = state
            rng.random(2 * used)
        if progress is not None:
            progress("drawing random starts", n, count)
    if counter is not None:
        counter.pairs += examined
    # (-pi, pi]: uniform on [-pi, pi) mirrored.
    headings = -rng.uniform(-math.pi, math.pi, size=count)
    return np.column_stack([placed, headings])

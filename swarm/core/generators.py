"""Generators that stand where a scenario gives a list: formation patches, random starts,
rows of obstacles. Pure functions; randomness comes from the `rng` passed in.
"""

from __future__ import annotations

import math

import numpy as np


class GeneratorError(ValueError):
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
    a1 = np.array([spacing, 0.0])
    a2 = np.array([0.5 * spacing, 0.5 * math.sqrt(3.0) * spacing])
    points = []
    for i in range(-rings, rings + 1):
        for j in range(-rings, rings + 1):
            ring = max(abs(i), abs(j), abs(i + j))
            if ring <= rings:
                p = i * a1 + j * a2
                angle = math.atan2(p[1], p[0]) % (2.0 * math.pi)
                points.append((ring, round(angle, 12), p[0], p[1]))
    points.sort()
    out = np.array([[p[2], p[3]] for p in points[:count]])
    out[np.abs(out) < 1e-12] = 0.0
    return out


def obstacle_row(start: tuple[float, float], end: tuple[float, float], pitch: float) -> np.ndarray:
    """Centres of obstacles from `start` to `end` (both included), about `pitch` [m] apart: (K, 2)."""
    start_a, end_a = np.asarray(start, float), np.asarray(end, float)
    length = float(np.linalg.norm(end_a - start_a))
    if pitch <= 0:
        raise GeneratorError(f"pitch must be > 0, got {pitch}")
    intervals = max(1, int(round(length / pitch)))
    if length == 0.0:
        return start_a[None, :].copy()
    s = np.linspace(0.0, 1.0, intervals + 1)
    return start_a[None, :] + s[:, None] * (end_a - start_a)[None, :]


def random_poses(
    rng: np.random.Generator,
    count: int,
    region: tuple[float, float, float, float],
    min_separation: float,
    obstacles: np.ndarray,
    obstacle_clearance: float,
    max_tries: int = 200_000,
) -> np.ndarray:
    """`count` poses uniform in region (xmin, xmax, ymin, ymax), headings uniform in (-pi, pi].

    Positions are drawn one at a time and rejected when closer than min_separation [m]
    to a robot already placed or closer than obstacle_clearance [m] to an obstacle
    centre (obstacles: (M, >= 2) array). Returns (count, 3). Deterministic in `rng`.
    """
    xmin, xmax, ymin, ymax = region
    if not (xmax > xmin and ymax > ymin):
        raise GeneratorError(f"region {list(region)} is empty (need xmin < xmax and ymin < ymax)")
    placed = np.empty((count, 2))
    n = 0
    tries = 0
    centres = np.asarray(obstacles, float)[:, :2] if len(obstacles) else np.empty((0, 2))
    while n < count:
        if tries >= max_tries:
            raise GeneratorError(
                f"placed only {n} of {count} robots in region {list(region)} with min_separation "
                f"{min_separation} m after {max_tries} draws: make the region larger"
            )
        tries += 1
        p = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)])
        if n and np.min(np.sum((placed[:n] - p) ** 2, axis=1)) < min_separation**2:
            continue
        if len(centres) and np.min(np.sum((centres - p) ** 2, axis=1)) < obstacle_clearance**2:
            continue
        placed[n] = p
        n += 1
    # (-pi, pi]: uniform on [-pi, pi) mirrored.
    headings = -rng.uniform(-math.pi, math.pi, size=count)
    return np.column_stack([placed, headings])

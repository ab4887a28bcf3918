"""The panels of the paper's Fig. 2 as PNG files (matplotlib, Agg, no pyplot state).

    paths = write_panels(recording, scenario, "out/")   # 12 panels + fig2.png overview

Panels: (a) paths in the x-y plane, (b)-(d) x, y, theta, (e)-(g) p_x, p_y, e_theta,
(h)-(i) v, omega, (j) freeze signal, (k) robot-robot distances, (l) largest errors (log).
Robot i keeps the same colour in every panel.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection
from matplotlib.colors import BoundaryNorm, ListedColormap
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from swarm.core.scenario import Scenario
from swarm.core.sim import Recording

if TYPE_CHECKING:
    from collections.abc import Sequence

LW = 0.6  # line width of per-robot lines
ERR_FLOOR = 1e-16  # floor for the log plot (l)
MAX_LINE_POINTS = 2_000_000  # panel (k) thins time so that pairs x samples stays below this
DENSE_PAIRS_N = 200  # panel (k): full (N, N) distances up to this N, sort-and-sweep above

# file stem -> (title, y label), in panel order
TITLES = {
    "a_paths": ("(a) robot paths in the x–y plane", "y [m]"),
    "b_x": ("(b) x coordinates", "x [m]"),
    "c_y": ("(c) y coordinates", "y [m]"),
    "d_theta": ("(d) orientations", "θ [rad], wrapped to (−π, π]"),
    "e_px": ("(e) position errors in x", "p_x [m]"),
    "f_py": ("(f) position errors in y", "p_y [m]"),
    "g_etheta": ("(g) orientation errors", "e_θ [rad]"),
    "h_v": ("(h) linear velocity control", "v [m/s]"),
    "i_omega": ("(i) angular velocity control", "ω [rad/s]"),
    "j_freeze": ("(j) 'freeze' signal (blue = frozen, line = count)", "robot id"),
    "k_distances": ("(k) robot–robot distances (pairs ever < 2R)", "distance [m]"),
    "l_errors": ("(l) largest errors over robots", "error [m], [rad]"),
}


def _colors(n: int) -> np.ndarray:
    """(n, 4) RGBA, one distinguishable colour per robot."""
    return colormaps["turbo"](np.linspace(0.05, 0.95, n) if n > 1 else [0.1])


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles [rad] wrapped into (-pi, pi]."""
    return np.pi - np.mod(np.pi - a, 2 * np.pi)


def _lines(ax, t: np.ndarray, y: np.ndarray, colors: np.ndarray | list[tuple[float, float, float, float]],
           break_jumps: bool = False) -> None:
    """One thin line per robot: t (S,) [s], y (S, N); with break_jumps, gaps at 2*pi wraps."""
    y = np.array(y, float)
    if break_jumps and len(t) > 1:
        jump = np.abs(np.diff(y, axis=0)) > np.pi
        y[1:][jump] = np.nan  # a NaN vertex breaks the path
    seg = np.stack([np.broadcast_to(t[:, None], y.shape), y], axis=-1).transpose(1, 0, 2)  # (N, S, 2)
    ax.add_collection(LineCollection(cast("Sequence[np.ndarray]", seg), colors=colors, linewidths=LW))  # N paths
    if len(t) == 1:
        ax.scatter(np.repeat(t, y.shape[1]), y[0], s=6, c=colors)
    ax.autoscale_view()
    ax.set_xlabel("t [s]")


def _clip_range(ax, y: np.ndarray) -> bool:
    """Limit the y axis to the 0.5-99.5 percentiles of y plus a margin; True if data were cut."""
    lo, hi = np.percentile(y, [0.5, 99.5])
    pad = 0.1 * (hi - lo) if hi > lo else 0.5 * max(abs(hi), 1.0)
    lo, hi = lo - pad, hi + pad
    if y.min() < lo or y.max() > hi:
        ax.set_ylim(lo, hi)
        return True
    return False


def _panel_paths(ax, rec: Recording, scn: Scenario, colors: np.ndarray) -> None:
    """(a): paths q[:, i, :2] [m], obstacles (r filled, R dashed), leader path, start poses, end formation."""
    q, n = rec.q, rec.q.shape[1]
    for x, y, r, big in scn.obstacles:
        ax.add_patch(Circle((x, y), r, fc="0.6", ec="0.4", lw=0.5))
        ax.add_patch(Circle((x, y), big, fill=False, ec="0.5", ls="--", lw=0.5))
    ax.add_collection(LineCollection(cast("Sequence[np.ndarray]", q[:, :, :2].transpose(1, 0, 2)), colors=colors,
                                     linewidths=LW))
    ax.plot(rec.leader[:, 0], rec.leader[:, 1], "k--", lw=1.2, label="leader", zorder=3)
    xy = np.concatenate([q[:, :, :2].reshape(-1, 2), rec.leader[:, :2]])
    tick = max(2.0 * scn.r, 0.025 * float(np.ptp(xy, axis=0).max()))  # heading tick length [m]

    def heading(pose, tick):  # (N, 3) -> (N, 2, 2) segments from the centre along theta
        tip = pose[:, :2] + tick * np.stack([np.cos(pose[:, 2]), np.sin(pose[:, 2])], axis=1)
        return np.stack([pose[:, :2], tip], axis=1)

    ax.add_collection(LineCollection(heading(q[0], tick), colors=colors, linewidths=1.2, zorder=4))
    ax.scatter(q[0, :, 0], q[0, :, 1], s=12, c=colors, ec="k", lw=0.3, marker="o", label="start (tick = heading)",
               zorder=4)
    for (x, y, _), c in zip(q[-1], colors):
        ax.add_patch(Circle((x, y), scn.r, fc=c, ec="k", lw=0.4, alpha=0.8, zorder=5))
    ax.add_collection(LineCollection(heading(q[-1], 2.0 * scn.r), colors="k", linewidths=0.8, zorder=6))
    slots = rec.leader[-1, :2] + scn.offsets
    ax.scatter(slots[:, 0], slots[:, 1], s=28, facecolors="none", edgecolors="k", lw=0.6, label="slots (end)",
               zorder=6)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.legend(loc="best", fontsize="x-small")
    sm = ScalarMappable(BoundaryNorm(np.arange(n + 1) - 0.5, n), ListedColormap(colors))
    ax.figure.colorbar(sm, ax=ax, label="robot id", shrink=0.8, ticks=np.arange(0, n, max(1, n // 8)))


def _panel_freeze(ax, rec: Recording) -> None:
    """(j): raster of frozen (S, N) bool, robot id on y; frozen count on a right axis."""
    t, fr = rec.t, rec.frozen
    s, n = fr.shape
    bins = min(s, 1000)  # keep every freeze visible: a bin is frozen if any sample in it is
    starts = np.linspace(0, s, bins, endpoint=False).astype(int)
    img = np.maximum.reduceat(fr.astype(np.uint8), starts, axis=0).T
    t1 = t[-1] if s > 1 and t[-1] > t[0] else t[0] + 1.0
    ax.imshow(img, aspect="auto", cmap=ListedColormap(["white", "#6baed6"]), vmin=0, vmax=1,
              interpolation="nearest", origin="lower",
              extent=(t[0], t1, -0.5, n - 0.5))
    ax.set_xlabel("t [s]")
    cnt = ax.twinx()
    cnt.plot(t, fr.sum(axis=1), color="darkred", lw=1.0)
    cnt.set_ylim(0, max(1, n) * 1.05)
    cnt.set_ylabel("number of frozen robots", color="darkred")
    cnt.tick_params(axis="y", colors="darkred")


def close_pairs(q: np.ndarray, within: float) -> np.ndarray:
    """(K, 2) index pairs i < j of robots ever closer than `within` [m] in q (S, N, 3)."""
    s, n = q.shape[:2]
    if n < 2:
        return np.zeros((0, 2), int)
    found = []
    for a in range(0, s, 256):  # chunks of samples keep memory small
        xy = q[a:a + 256, :, :2]
        if n <= DENSE_PAIRS_N:
            d2 = np.sum((xy[:, :, None, :] - xy[:, None, :, :]) ** 2, axis=-1)  # (s, N, N)
            i, j = np.nonzero(np.triu((d2 < within * within).any(axis=0), 1))
            found.append(i * n + j)
            continue
        order = np.argsort(xy[:, :, 0], axis=1)  # sort and sweep along x
        sx = np.take_along_axis(xy, order[:, :, None], axis=1)
        for k in range(1, n):
            dx = sx[:, k:, 0] - sx[:, :-k, 0]
            near = dx < within
            if not near.any():
                break
            dy = sx[:, k:, 1] - sx[:, :-k, 1]
            hit = near & (dx * dx + dy * dy < within * within)
            i, j = order[:, :-k][hit], order[:, k:][hit]
            found.append(np.minimum(i, j) * n + np.maximum(i, j))
    keys = np.unique(np.concatenate(found)) if found else np.zeros(0, int)
    return np.stack([keys // n, keys % n], axis=1)


def _panel_distances(ax, rec: Recording, scn: Scenario) -> None:
    """(k): |p_i - p_j| [m] over time for pairs ever within 2R; lines at r and R; the minimum in black."""
    pairs = close_pairs(rec.q, 2 * scn.R)
    t = rec.t
    if len(pairs):
        d = np.hypot(*(rec.q[:, pairs[:, 0], :2] - rec.q[:, pairs[:, 1], :2]).transpose(2, 0, 1))  # (S, K)
        step = max(1, math.ceil(d.size / MAX_LINE_POINTS))
        _lines(ax, t[::step], d[::step], colors=[(0.2, 0.3, 0.7, 0.5)])
        ax.plot(t, d.min(axis=1), color="k", lw=1.0, label=f"min over pairs (sampled min {d.min():.3g} m)")
    else:
        ax.text(0.5, 0.5, "no pair ever within 2R", transform=ax.transAxes, ha="center")
    ax.axhline(scn.r, color="tab:red", ls="--", lw=1.0, label=f"r = {scn.r:g} m")
    ax.axhline(scn.R, color="tab:orange", ls=":", lw=1.0, label=f"R = {scn.R:g} m")
    ax.set_ylim(0, 2.2 * scn.R)
    if len(t) > 1 and t[-1] > t[0]:
        ax.set_xlim(t[0], t[-1])
    ax.set_xlabel("t [s]")
    ax.legend(loc="upper right", fontsize="x-small")
    ax.set_title(f"{TITLES['k_distances'][0]}, {len(pairs)} pairs", fontsize="medium")


def _panel_errors(ax, rec: Recording) -> None:
    """(l): max_i ||(p_x, p_y)|| [m] and max_i |e_theta| [rad] per sample, log axis floored at 1e-16."""
    n = rec.err.shape[1]
    pos = np.hypot(rec.err[:, :, 0], rec.err[:, :, 1]).max(axis=1) if n else np.zeros(len(rec.t))
    ang = np.abs(rec.err[:, :, 2]).max(axis=1) if n else np.zeros(len(rec.t))
    marker = "." if len(rec.t) < 3 else None
    ax.semilogy(rec.t, np.maximum(pos, ERR_FLOOR), lw=1.0, marker=marker, label="max ‖(p_x, p_y)‖ [m]")
    ax.semilogy(rec.t, np.maximum(ang, ERR_FLOOR), lw=1.0, marker=marker, label="max |e_θ| [rad]")
    ax.set_ylim(ERR_FLOOR / 3, None)
    ax.set_xlabel("t [s]")
    ax.legend(loc="upper right", fontsize="x-small")


def _draw(stem: str, ax, rec: Recording, scn: Scenario, colors: np.ndarray) -> None:
    """Draw panel `stem` (a key of TITLES) on ax."""
    title, ylabel = TITLES[stem]
    ax.set_title(title, fontsize="medium")
    if stem == "a_paths":
        _panel_paths(ax, rec, scn, colors)
    elif stem == "j_freeze":
        _panel_freeze(ax, rec)
    elif stem == "k_distances":
        _panel_distances(ax, rec, scn)
    elif stem == "l_errors":
        _panel_errors(ax, rec)
    else:
        arr, col = {"b_x": (rec.q, 0), "c_y": (rec.q, 1), "d_theta": (rec.q, 2), "e_px": (rec.err, 0),
                    "f_py": (rec.err, 1), "g_etheta": (rec.err, 2), "h_v": (rec.cmd, 0), "i_omega": (rec.cmd, 1)}[stem]
        y = _wrap(arr[:, :, col]) if stem == "d_theta" else arr[:, :, col]  # (S, N)
        _lines(ax, rec.t, y, colors, break_jumps=stem in ("d_theta", "g_etheta"))
        if stem in ("h_v", "i_omega") and y.size and _clip_range(ax, y):
            ax.set_title(f"{title} (clipped: 0.5–99.5 %)", fontsize="medium")
        if stem in ("d_theta", "g_etheta"):
            ax.set_ylim(-3.3, 3.3)
    ax.set_ylabel(ylabel)
    ax.grid(True, lw=0.3, alpha=0.5)


def _paths_size(rec: Recording) -> tuple[float, float]:
    """Figure size [in] for panel (a) that roughly follows the aspect of the paths."""
    xy = np.concatenate([rec.q[:, :, :2].reshape(-1, 2), rec.leader[:, :2]])
    dx, dy = np.maximum(np.ptp(xy, axis=0), 1.0)
    return 10.0, float(np.clip(7.5 * dy / dx + 1.5, 4.0, 9.0))


def write_panels(recording: Recording, scenario: Scenario, out_dir) -> list[Path]:
    """Write the 12 panels of Fig. 2 (a_paths.png ... l_errors.png) and fig2.png into out_dir.

    recording: samples of one run (swarm.core.sim.Recording); scenario: the Scenario that was run.
    Returns the paths written, panels first, the overview last.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    colors = _colors(recording.q.shape[1])
    written = []
    for stem in TITLES:
        fig = Figure(figsize=_paths_size(recording) if stem == "a_paths" else (6.4, 4.2))
        FigureCanvasAgg(fig)  # fixed margins: a layout engine would double the drawing time
        fig.subplots_adjust(left=0.11, right=0.88 if stem == "j_freeze" else 0.96, bottom=0.11, top=0.92)
        _draw(stem, fig.add_subplot(), recording, scenario, colors)
        written.append(out / f"{stem}.png")
        fig.savefig(written[-1], dpi=120)
    fig = Figure(figsize=(24, 15))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.04, right=0.97, bottom=0.05, top=0.93, wspace=0.3, hspace=0.3)
    for ax, stem in zip(fig.subplots(3, 4).ravel(), TITLES):
        _draw(stem, ax, recording, scenario, colors)
    fig.suptitle(f"{scenario.name}: N = {scenario.n}, dt = {scenario.dt:g} s, seed = {scenario.seed}",
                 fontsize="x-large")
    written.append(out / "fig2.png")
    fig.savefig(written[-1], dpi=90)
    return written

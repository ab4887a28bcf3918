"""What `swarm campaign` draws: three PNG plots against the drop probability and index.html.

    paths = write_plots(runs, "out/", Bodies(r=0.25, obstacle_r=0.25, duration=120.0), title="paper-50hz")
    write_index("out/", command, columns, summary, flagged, paths)
    write_up_section("out/", up_rows, asked=3)       # swarm campaign --up: its section, replaced each time

`runs` are the rows of runs.csv as dicts (values as Python numbers, None for an empty cell): every plot
reads `drop`, `seed` and a metric. Each run is one point, the seeds of one p spread side by side
(so the spread over seeds shows), with the median over seeds as a line:

- convergence.png: converged_at_s [s] against p; a run that did not converge is a red cross at the top
  (at the end of the run), counted in the legend;
- distance.png: min_robot_distance_m and min_obstacle_distance_m [m] against p, with r drawn (a
  robot closer than r to another body collided);
- error.png: final_position_error_max_m [m] and final_orientation_error_max_rad [rad] against p, log
  scale, with the convergence thresholds.

matplotlib's Agg canvas only (no pyplot state), as swarm.view.plots.
"""

from __future__ import annotations

import html
import math
import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from swarm.core.metrics import CONVERGED_ANGLE_RAD, CONVERGED_POSITION_M

ERR_FLOOR = 1e-16  # an error of exactly 0 is drawn here on the log axis
PLOTS = {  # file name -> caption
    "convergence.png": "convergence time against the drop probability",
    "distance.png": "smallest distances against the drop probability",
    "error.png": "final formation error against the drop probability",
}


@dataclass(frozen=True)
class Bodies:
    """What the plots draw besides the runs: r [m] (robots), the obstacles' smallest r [m] (None without
    obstacles), the runs' duration [s] (where a run that did not converge is drawn)."""

    r: float
    obstacle_r: float | None
    duration: float


def _spread(runs: Sequence[dict]) -> tuple[dict[float, list[dict]], dict[int, float], float]:
    """The runs by p (sorted), each seed's horizontal offset [in units of p] and the width of a group."""
    by_p: dict[float, list[dict]] = {}
    for m in runs:
        by_p.setdefault(float(m["drop"]), []).append(m)
    ps = sorted(by_p)
    gaps = [b - a for a, b in zip(ps, ps[1:])]
    width = 0.5 * min(gaps) if gaps else 0.05
    seeds = sorted({m["seed"] for m in runs})
    step = width / max(1, len(seeds))
    offset = {s: (i - (len(seeds) - 1) / 2) * step for i, s in enumerate(seeds)}
    return {p: by_p[p] for p in ps}, offset, width


def _new(title: str, ylabel: str):
    fig = Figure(figsize=(7.0, 4.4))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.12, top=0.9)
    ax = fig.add_subplot()
    ax.set_title(title, fontsize="medium")
    ax.set_xlabel("drop probability p (one drop rule of class all: states, poses, commands, references)")
    ax.set_ylabel(ylabel)
    ax.grid(True, lw=0.3, alpha=0.5)
    return fig, ax


def _xlim(ax, by_p: dict, width: float) -> None:
    ps = list(by_p)
    ax.set_xlim(ps[0] - width, ps[-1] + width)
    ax.set_xticks(ps)
    ax.set_xticklabels([f"{p:g}" for p in ps])


def _series(ax, by_p: dict, offset: dict, key: str, floor: float | None = None, **style) -> None:
    """One point per run that has `key` (offset by seed), and the median over those runs per p as a line."""
    xs, ys, mx, my = [], [], [], []
    for p, group in by_p.items():
        vals = []
        for m in group:
            v = m.get(key)
            if v is None:
                continue
            v = max(float(v), floor) if floor is not None else float(v)
            xs.append(p + offset[m["seed"]])
            ys.append(v)
            vals.append(v)
        if vals:
            mx.append(p)
            my.append(statistics.median(vals))
    label = style.pop("label")
    color = style.pop("color")
    ax.scatter(xs, ys, s=16, color=color, alpha=0.75, label=f"{label}, one point a run", zorder=3, **style)
    if mx:
        ax.plot(mx, my, color=color, lw=1.2, label=f"{label}, median over seeds", zorder=2)


def plot_convergence(runs: Sequence[dict], path: Path, bodies: Bodies, title: str) -> None:
    by_p, offset, width = _spread(runs)
    fig, ax = _new(f"{title}: convergence time", "converged at [s] (every live robot within 0.05 m, 0.05 rad)")
    _series(ax, by_p, offset, "converged_at_s", label="converged", color="tab:blue")
    top = bodies.duration
    stuck = [(p + offset[m["seed"]], top) for p, group in by_p.items() for m in group
             if m.get("converged_at_s") is None]
    ax.axhline(top, color="0.5", ls=":", lw=1.0)
    if stuck:
        ax.scatter([x for x, _ in stuck], [y for _, y in stuck], marker="x", s=40, color="tab:red", zorder=4,
                   label=f"not converged by the end ({top:g} s): {len(stuck)} run{'s' if len(stuck) != 1 else ''}")
    ax.set_ylim(0, 1.08 * top)
    _xlim(ax, by_p, width)
    ax.legend(loc="lower right", fontsize="x-small")
    fig.savefig(path, dpi=110)


def plot_distance(runs: Sequence[dict], path: Path, bodies: Bodies, title: str) -> None:
    by_p, offset, width = _spread(runs)
    fig, ax = _new(f"{title}: smallest distances over the run", "smallest distance, centre to centre [m]")
    _series(ax, by_p, offset, "min_robot_distance_m", label="robot-robot", color="tab:blue")
    if bodies.obstacle_r is not None:
        _series(ax, by_p, offset, "min_obstacle_distance_m", label="robot-obstacle", color="tab:green", marker="^")
    ax.axhline(bodies.r, color="tab:red", ls="--", lw=1.0, label=f"r = {bodies.r:g} m (closer: a collision)")
    if bodies.obstacle_r is not None and bodies.obstacle_r != bodies.r:
        ax.axhline(bodies.obstacle_r, color="tab:purple", ls="--", lw=1.0,
                   label=f"obstacles' smallest r = {bodies.obstacle_r:g} m")
    ax.set_ylim(0, None)
    _xlim(ax, by_p, width)
    ax.legend(loc="best", fontsize="x-small")
    fig.savefig(path, dpi=110)


def plot_error(runs: Sequence[dict], path: Path, bodies: Bodies, title: str) -> None:
    by_p, offset, width = _spread(runs)
    fig, ax = _new(f"{title}: final formation error (at the end of the run)", "largest error over live robots")
    ax.set_yscale("log")
    _series(ax, by_p, offset, "final_position_error_max_m", floor=ERR_FLOOR, label="position [m]", color="tab:blue")
    _series(ax, by_p, offset, "final_orientation_error_max_rad", floor=ERR_FLOOR, label="orientation [rad]",
            color="tab:orange", marker="s")
    if CONVERGED_ANGLE_RAD == CONVERGED_POSITION_M:
        ax.axhline(CONVERGED_POSITION_M, color="0.4", ls="--", lw=1.0,
                   label=f"converged below {CONVERGED_POSITION_M:g} m, {CONVERGED_ANGLE_RAD:g} rad")
    else:
        ax.axhline(CONVERGED_POSITION_M, color="tab:blue", ls="--", lw=1.0,
                   label=f"converged below {CONVERGED_POSITION_M:g} m")
        ax.axhline(CONVERGED_ANGLE_RAD, color="tab:orange", ls="--", lw=1.0,
                   label=f"converged below {CONVERGED_ANGLE_RAD:g} rad")
    values = [max(float(m[k]), ERR_FLOOR) for m in runs for k in ("final_position_error_max_m",
                                                                   "final_orientation_error_max_rad")
              if m.get(k) is not None]
    low = min(values + [min(CONVERGED_POSITION_M, CONVERGED_ANGLE_RAD)])
    ax.set_ylim(low / 10, None)  # down to the smallest error (ERR_FLOOR for an exact 0)
    _xlim(ax, by_p, width)
    ax.legend(loc="lower right", fontsize="x-small")
    fig.savefig(path, dpi=110)


def write_plots(runs: Sequence[dict], out_dir, bodies: Bodies, title: str) -> list[Path]:
    """convergence.png, distance.png and error.png in out_dir (runs: the rows of runs.csv, at least one).
    Returns their paths."""
    if not runs:
        raise ValueError("no run to plot")
    out = Path(out_dir)
    paths = []
    for name, draw in (("convergence.png", plot_convergence), ("distance.png", plot_distance),
                       ("error.png", plot_error)):
        paths.append(out / name)
        draw(runs, paths[-1], bodies, title)
    return paths


# --------------------------------------------------------------------------- the page

_CSS = """body{font-family:sans-serif;margin:1.5em;max-width:1200px}
table{border-collapse:collapse;font-size:0.85em}td,th{border:1px solid #ccc;padding:2px 6px;text-align:right;white-space:nowrap}
th{background:#eee}td.l,th.l{text-align:left}code,pre{background:#f4f4f4;padding:2px 4px}
pre{white-space:pre-wrap}.warning{color:#a00}figure{display:inline-block;margin:0.5em}img{max-width:100%}
.scroll{overflow-x:auto}"""


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.4g}" if math.isfinite(v) else str(v)
    return str(v)


def _table(columns: Sequence[str], rows: Sequence[dict], left: Sequence[str] = (), code: Sequence[str] = ()) -> str:
    """An HTML table of rows (dicts) by columns; `left` columns left-aligned, `code` columns in code font."""
    esc = html.escape
    cls = {c: " class='l'" if c in left else "" for c in columns}

    def td(c: str, v) -> str:
        text = esc(_cell(v))
        return f"<td{cls[c]}>{f'<code>{text}</code>' if c in code and text else text}</td>"

    head = "".join(f"<th{cls[c]}>{esc(c)}</th>" for c in columns)
    body = "".join("<tr>" + "".join(td(c, r.get(c)) for c in columns) + "</tr>" for r in rows)
    return f"<div class='scroll'><table><tr>{head}</tr>{body}</table></div>"


@dataclass(frozen=True)
class Flagged:
    """A run to list on the page: its row of runs.csv, why (collided, did not converge, failed) and the
    command line that replays it alone."""

    row: dict
    why: str
    replay: str


def write_index(out_dir, command: str, columns: Sequence[str], summary: Sequence[dict], flagged: Sequence[Flagged],
                plots: Sequence[Path], notes: Sequence[str] = ()) -> Path:
    """index.html: the command line, notes (an interrupted campaign), summary.csv as a table, the plots,
    then the runs that collided, did not converge or failed, each with the command that replays it."""
    esc = html.escape
    out = Path(out_dir)
    parts = ["<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>swarm campaign</title>",
             f"<style>{_CSS}</style></head><body>", "<h1>swarm campaign</h1>", f"<pre>{esc(command)}</pre>"]
    parts += [f"<p class='warning'>{esc(n)}</p>" for n in notes]
    parts += ["<h2>Summary (one row per drop probability)</h2>",
              "<p>Files: <a href='summary.csv'>summary.csv</a> · <a href='runs.csv'>runs.csv</a> (one row a run). "
              "Columns named <code>wallclock.*</code> are wall-clock times; every other column is the same "
              "whenever the same command runs.</p>",
              _table(columns, summary, left=("scenario",)), "<h2>Plots</h2>"]
    for p in plots:
        parts.append(f"<figure><a href='{esc(p.name)}'><img src='{esc(p.name)}' alt='{esc(PLOTS.get(p.name, p.name))}'>"
                     f"</a><figcaption>{esc(PLOTS.get(p.name, p.name))}</figcaption></figure>")
    parts.append(f"<h2>Runs that collided, did not converge or failed ({len(flagged)})</h2>")
    if flagged:
        cols = ("seed", "drop", "why", "collisions", "min_robot_distance_m", "min_obstacle_distance_m",
                "final_position_error_max_m", "final_orientation_error_max_rad", "robots_alive_at_end", "replay")
        rows = [{**f.row, "why": f.why, "replay": f.replay} for f in flagged]
        parts.append(_table(cols, rows, left=("why", "replay"), code=("replay",)))
    else:
        parts.append("<p>None: every run converged with no collision.</p>")
    parts.append("</body></html>\n")
    path = out / "index.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


UP_START, UP_END = "<!-- up-check:start -->", "<!-- up-check:end -->"
UP_SHOWN = ("row", "seed", "drop", "result", "first_differing_tick", "robots_differing", "metrics_differing", "why",
            "up_said", "collisions", "converged_at_s", "files", "wallclock.up_s", "wallclock.sim_s")


def write_up_section(out_dir, rows: Sequence[dict], asked: int, note: str | None = None) -> Path | None:
    """index.html's section on `swarm campaign --up`: the rows of up.csv (text cells) checked against
    swarm sim, replacing an earlier such section (None when the campaign has no index.html)."""
    esc = html.escape
    path = Path(out_dir) / "index.html"
    if not path.is_file():
        return None
    same = sum(1 for r in rows if r.get("result") == "identical")
    parts = [UP_START, f"<h2>Lock-step swarm up against swarm sim ({same} of {len(rows)} identical)</h2>",
             f"<p>The first {asked} runs of runs.csv again as lock-step <code>swarm up</code> (one process per robot "
             "over zenoh), each compared with <code>swarm sim</code> of the same scenario, seed, drop and faults: "
             "every robot's pose at every tick, bit for bit, and the metrics. <a href='up.csv'>up.csv</a> has every "
             "column, with each row's <code>swarm up</code> command.</p>"]
    if note:
        parts.append(f"<p class='warning'>{esc(note)}</p>")
    parts += [_table(UP_SHOWN, rows, left=("result", "robots_differing", "metrics_differing", "why", "up_said", "files")),
              UP_END]
    block = "\n".join(parts)
    text = path.read_text(encoding="utf-8")
    a, b = text.find(UP_START), text.find(UP_END)
    if 0 <= a < b:
        text = text[:a] + block + text[b + len(UP_END):]
    else:
        at = text.rfind("</body>")
        text = (text[:at] + block + "\n" + text[at:]) if at >= 0 else text + block + "\n"
    path.write_text(text, encoding="utf-8")
    return path

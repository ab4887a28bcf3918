"""Reading a recording back (swarm.view.record's MCAP file): samples, frames for replay, a report.

    run = read_recording("run.mcap")      # scenario, sim.Recording, metrics, events
    for f in pace(iter_frames("run.mcap"), speed=2.0):
        view.show(f.q, f.alive, f.frozen)  # f.t [s], q (N, 3)
    write_report("run.mcap", "out/")      # Fig. 2 panels (swarm.view.plots) + index.html

The same reader serves a live recording (`swarm up --record`) and an in-process one (`swarm sim
--record`): both have the channels of swarm.view.record. A file without its footer (a run killed before
the recorder finished it) is read sequentially up to its last complete chunk; `recovery(path)` and
Run.recovered say how much of it came back. The samples' errors are recomputed against the
live leader reference of the stored scenario, exactly as the simulator computes them (swarm.core.kernel:
p = (x_l + d_i) - x_i, e_theta = wrap(theta_l - theta_i)), never taken from a frozen snapshot.
Every failure to read is a ReportError naming the file and the reason.
"""

from __future__ import annotations

import html
import json
import math
import time
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, cast

import numpy as np

from swarm.core import kinematics, law
from swarm.view.faultmarks import FaultMarks, robot_list
from swarm.view.record import (METRIC_KEYS, TOPIC_CMD, TOPIC_EVENTS, TOPIC_FAULTS, TOPIC_METRICS, TOPIC_SCENARIO,
                               TOPIC_SNAPSHOT, TOPIC_STATUS)
from swarm.core.errors import ScenarioError
from swarm.core.scenario import Scenario
from swarm.core.sim import Recording
from swarm.core.errors import SwarmError

FIRST_EVENTS = 50  # events listed one by one in index.html
FIRST_FAULTS = 500  # fault events listed one by one in index.html
STATUS_FRESH_S = 1.0  # replay: a robot's recorded status counts for its stale-data ring this long [simulated s]
_MAGIC = b"\x89MCAP0\r\n"  # an MCAP file starts and ends with it


class ReportError(SwarmError, ValueError):
    """A file that cannot be read as a swarm recording; the message names the file and the reason."""


@dataclass(frozen=True)
class Recovery:
    """What came back from a recording without its footer: the snapshots read, the last one's time [s],
    the run's planned duration [s] (None: the scenario was lost too), the bytes read and the file's size."""

    snapshots: int
    last_t: float | None
    duration: float | None
    bytes_read: int
    size: int

    def message(self) -> str:
        upto = "" if self.last_t is None else f" up to t = {self.last_t:.4g} s"
        of = "" if self.duration is None else f" of the {self.duration:g} s run"
        lost = self.size - self.bytes_read
        tail = f"; its last {lost} bytes, an incomplete chunk, are lost" if lost > 0 else ""
        return (f"recovered {self.snapshots} snapshots{upto}{of}: the recording has no footer (the run was killed "
                f"or crashed before the recorder finished the file){tail}")


@dataclass
class Run:
    """A recording read back. recording: samples at the recorded snapshots (swarm.core.sim.Recording);
    metrics: the run's metrics dict (None if the run never wrote them); events: /events dicts in time
    order; info: the /scenario message without its TOML (source, record_hz, fleet, ...)."""

    path: Path
    scenario: Scenario
    recording: Recording
    metrics: dict | None
    events: list[dict]
    info: dict
    counts: dict[str, int]  # messages per topic in the file
    recovered: Recovery | None = None  # set when the file had no footer
    faults: list[dict] = field(default_factory=list)  # /faults messages (fault events) in time order


@dataclass(frozen=True)
class Frame:
    """One snapshot for replay: t [s], q (N, 3) x, y [m], theta [rad]; stopped, alive, frozen (N,) bool.
    Rows are robot ids; a robot missing from the snapshot has NaN pose and alive False.
    With iter_frames(..., faults=True) also (N,) bool: killed, hung, cut (the fault events up to t) and
    stale_data (the robot's newest status, at most STATUS_FRESH_S old, counts stale neighbour states);
    else None."""

    t: float
    seq: int
    q: np.ndarray
    stopped: np.ndarray
    alive: np.ndarray
    frozen: np.ndarray
    killed: np.ndarray | None = None
    hung: np.ndarray | None = None
    cut: np.ndarray | None = None
    stale_data: np.ndarray | None = None


# --------------------------------------------------------------------------- reading


def _messages(path: Path, topics: list[str] | None = None, counts: dict[str, int] | None = None,
              salvage: dict | None = None) -> Iterator[tuple[str, int, dict]]:
    """(topic, log_time [ns], decoded JSON) of every message of `topics` (None: all), in log-time order;
    ReportError on any fault. counts, if given, receives the file's message count per topic.

    A file that starts as MCAP but has no footer (the run was killed) is read sequentially, up to its
    last complete chunk; then `salvage`, if given, receives "bytes_read" and "size"."""
    from mcap.reader import make_reader

    try:
        f = open(path, "rb")
    except FileNotFoundError:
        raise ReportError(f"{path}: no such file") from None
    except OSError as e:
        raise ReportError(f"{path}: cannot read: {e.strerror or e}") from None
    with f:
        head = f.read(len(_MAGIC))
        if not head:
            raise ReportError(f"{path}: empty file, not an MCAP recording")
        if head != _MAGIC:
            raise ReportError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")
        size = path.stat().st_size
        f.seek(-min(len(_MAGIC), size), 2)
        if f.read() != _MAGIC or size < 2 * len(_MAGIC):
            yield from _salvaged(path, f, size, topics, counts, salvage)
            return
        f.seek(0)
        try:
            reader = make_reader(f)
            summary = reader.get_summary()
        except Exception as e:  # McapError, or struct/EOF errors on damaged files
            raise ReportError(f"{path}: corrupt or truncated MCAP file ({type(e).__name__}: {e})") from None
        if summary is None:
            raise ReportError(f"{path}: truncated MCAP file (no summary: the recorder did not finish it)")
        if counts is not None and summary.statistics is not None:
            for cid, c in summary.statistics.channel_message_counts.items():
                if cid in summary.channels:
                    counts[summary.channels[cid].topic] = counts.get(summary.channels[cid].topic, 0) + c
        try:
            for _schema, channel, message in reader.iter_messages(topics=topics):
                yield channel.topic, message.log_time, _json(path, channel.topic, message)
        except ReportError:
            raise
        except Exception as e:
            raise ReportError(f"{path}: corrupt or truncated MCAP file ({type(e).__name__}: {e})") from None


def _json(path: Path, topic: str, message) -> dict:
    try:
        return json.loads(message.data)
    except ValueError as e:
        raise ReportError(f"{path}: {topic} message at log time {message.log_time} ns is not JSON: {e}") from None


def _salvaged(path: Path, f, size: int, topics: list[str] | None, counts: dict[str, int] | None,
              salvage: dict | None) -> Iterator[tuple[str, int, dict]]:
    """The messages of a file without a footer, read record by record (mcap's non-seeking StreamReader)
    until the first incomplete or damaged record, then in log-time order (stable) like the indexed
    reader gives them. The recorder flushes complete chunks at least every second (swarm.view.record),
    so this is the run up to about a second before it was killed."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    f.seek(0)
    stream = StreamReader(f, skip_magic=False)
    channels: dict[int, str] = {}
    kept: list[tuple[int, int, str, Message]] = []
    read_to = len(_MAGIC)
    try:
        for record in stream.records:
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                topic = channels.get(record.channel_id)
                if topic is None:
                    continue
                if counts is not None:
                    counts[topic] = counts.get(topic, 0) + 1
                if topics is None or topic in topics:
                    kept.append((record.log_time, len(kept), topic, record))
            read_to = f.tell()
    except Exception:  # the incomplete end (EndOfFile), or damage: what came before stands
        pass
    if salvage is not None:
        salvage["bytes_read"], salvage["size"] = min(read_to, size), size
    kept.sort(key=lambda m: (m[0], m[1]))
    for log_time, _k, topic, message in kept:
        yield topic, log_time, _json(path, topic, message)


def _scenario(path: Path, msg: dict | None) -> tuple[Scenario, dict]:
    from swarm.core import scenario_file

    if msg is None:
        raise ReportError(f"{path}: no {TOPIC_SCENARIO} message: not a swarm recording")
    try:
        doc = tomllib.loads(msg["toml"])
        spec = scenario_file.parse(doc, f"{path}:{TOPIC_SCENARIO}", str(msg.get("name", path.stem)))
        scn = scenario_file.resolve(spec)
    except (KeyError, TypeError, tomllib.TOMLDecodeError, ScenarioError) as e:
        raise ReportError(f"{path}: the recorded scenario cannot be rebuilt: {e}") from None
    info = {k: v for k, v in msg.items() if k != "toml"}
    return scn, info


def read_scenario(path) -> tuple[Scenario, dict]:
    """The recorded Scenario and the /scenario message's other fields (reads only that channel)."""
    path = Path(path)
    salvage: dict = {}
    for _topic, _t, data in _messages(path, [TOPIC_SCENARIO], None, salvage):
        return _scenario(path, data)
    if salvage:
        raise ReportError(f"{path}: no {TOPIC_SCENARIO} message came back: the recording has no footer (the run "
                          "was killed or crashed before the recorder finished the file)")
    return _scenario(path, None)


_Columns = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _columns(path: Path, d: dict, n: int) -> _Columns:
    """Rows by robot id of one snapshot message: x, y, theta, v, w (N,) floats, stopped, alive, frozen bools."""
    try:
        ids = np.asarray(d["id"], np.int64)
        if ids.size and (ids.min() < 0 or ids.max() >= n):
            raise ValueError(f"robot id {int(ids.max())} outside the scenario's 0..{n - 1}")
        cols = [np.full(n, np.nan) for _ in range(5)]
        for c, name in zip(cols, ("x", "y", "theta", "v", "w")):
            c[ids] = np.asarray(d[name], float)
        flags = [np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)]
        flags[0][:] = True  # a robot missing from the snapshot counts as stopped and not alive
        for c, name in zip(flags, ("stopped", "alive", "frozen")):
            c[ids] = np.asarray(d[name], bool)
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise ReportError(f"{path}: bad {TOPIC_SNAPSHOT} message at t = {d.get('t')!r}: {e}") from None
    return cast(_Columns, (*cols, *flags))  # 5 columns, 3 flags


def _wrap(a: np.ndarray) -> np.ndarray:
    """swarm.core.law.wrap_angle elementwise, bit for bit (numpy for angles in range, the scalar law otherwise)."""
    out = np.array(a, float)
    bad = ~((out > -math.pi) & (out <= math.pi))
    if bad.any():
        out[bad] = [law.wrap_angle(v) for v in out[bad].tolist()]
    return out


def live_errors(scn: Scenario, t: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """err (S, N, 3) p_x, p_y [m], e_theta [rad] against the live leader reference, and leader (S, 3),
    for samples at times t (S,) with poses q (S, N, 3): the simulator's formulas, float for float."""
    table = scn.leader.table()
    leader = np.array([kinematics.leader_state(table, float(tk))[:3] for tk in t], float).reshape(-1, 3)
    off = np.asarray(scn.offsets, float)
    err = np.empty_like(q)
    err[:, :, 0] = (leader[:, 0:1] + off[None, :, 0]) - q[:, :, 0]
    err[:, :, 1] = (leader[:, 1:2] + off[None, :, 1]) - q[:, :, 1]
    err[:, :, 2] = _wrap(leader[:, 2:3] - q[:, :, 2])
    return err, leader


def read_recording(path) -> Run:
    """Read a whole recording: the scenario, the samples (one per recorded snapshot), metrics, events.

    Recording.cmd at a sample is robot i's newest recorded command with t <= the sample's t (the one
    computed at that step when it was recorded), else the snapshot's v, w (the command being applied).
    """
    path = Path(path)
    scn_msg = None
    snaps: list[dict] = []
    cmds: dict[int, list[tuple[float, float, float]]] = {}
    events: list[dict] = []
    metrics = None
    counts: dict[str, int] = {}
    salvage: dict = {}
    faults: list[dict] = []
    for topic, _t, d in _messages(path, [TOPIC_SCENARIO, TOPIC_SNAPSHOT, TOPIC_CMD, TOPIC_EVENTS, TOPIC_FAULTS,
                                         TOPIC_METRICS], counts, salvage):
        if topic == TOPIC_SNAPSHOT:
            snaps.append(d)
        elif topic == TOPIC_FAULTS:
            faults.append(_fault(path, d))
        elif topic == TOPIC_CMD:
            try:
                cmds.setdefault(int(d["id"]), []).append((float(d["t"]), float(d["v"]), float(d["w"])))
            except (KeyError, TypeError, ValueError) as e:
                raise ReportError(f"{path}: bad {TOPIC_CMD} message {str(d)[:80]}: {e}") from None
        elif topic == TOPIC_EVENTS:
            events.append(d)
        elif topic == TOPIC_METRICS:
            metrics = d
        elif topic == TOPIC_SCENARIO and scn_msg is None:
            scn_msg = d
    recovered = None
    if salvage:
        last = max((float(d["t"]) for d in snaps if isinstance(d.get("t"), (int, float))), default=None)
        duration = scn_msg.get("duration") if isinstance(scn_msg, dict) else None
        recovered = Recovery(len(snaps), last, duration if isinstance(duration, (int, float)) else None,
                             salvage["bytes_read"], salvage["size"])
        if scn_msg is None or not snaps:
            raise ReportError(f"{path}: {recovered.message()}")
    scn, info = _scenario(path, scn_msg)
    if not snaps:
        raise ReportError(f"{path}: no {TOPIC_SNAPSHOT} messages: nothing was recorded")
    n, s = scn.n, len(snaps)
    t = np.empty(s)
    q = np.empty((s, n, 3))
    cmd = np.empty((s, n, 2))
    frozen = np.zeros((s, n), bool)
    for k, d in enumerate(snaps):
        try:
            t[k] = float(d["t"])
        except (KeyError, TypeError, ValueError) as e:
            raise ReportError(f"{path}: bad {TOPIC_SNAPSHOT} message without a time: {e}") from None
        x, y, th, v, w, _stopped, _alive, fr = _columns(path, d, n)
        q[k, :, 0], q[k, :, 1], q[k, :, 2] = x, y, th
        cmd[k, :, 0], cmd[k, :, 1] = v, w
        frozen[k] = fr
    tol = 1e-6 * scn.dt
    for i, rows in cmds.items():
        if not 0 <= i < n:
            raise ReportError(f"{path}: {TOPIC_CMD} message for robot {i}; the scenario has 0..{n - 1}")
        rows.sort(key=lambda r: r[0])
        ct = np.array([r[0] for r in rows])
        at = np.searchsorted(ct, t + tol, side="right") - 1
        has = at >= 0
        vw = np.array([(r[1], r[2]) for r in rows])
        cmd[has, i, :] = vw[at[has]]
    err, leader = live_errors(scn, t, q)
    events.sort(key=lambda e: e.get("t", 0.0) if isinstance(e.get("t"), (int, float)) else 0.0)
    faults.sort(key=lambda e: e["t"])
    return Run(path, scn, Recording(t, q, err, cmd, frozen, leader), metrics, events, info, counts, recovered,
               faults)


def _fault(path: Path, d: dict) -> dict:
    """A /faults message, checked: t (number), seq (int), event (str), robots (list of ints), detail (str)."""
    ok = (isinstance(d, dict) and isinstance(d.get("t"), (int, float)) and not isinstance(d.get("t"), bool)
          and math.isfinite(d["t"]) and isinstance(d.get("seq"), int) and isinstance(d.get("event"), str)
          and isinstance(d.get("robots"), list) and all(isinstance(i, int) and not isinstance(i, bool) and i >= 0
                                                        for i in d["robots"])
          and isinstance(d.get("detail", ""), str))
    if not ok:
        raise ReportError(f"{path}: bad {TOPIC_FAULTS} message {str(d)[:80]}")
    return d


def recovery(path) -> Recovery | None:
    """None for a finished recording; for one without its footer (a killed run), what can be read back:
    ReportError if not even its scenario and one snapshot came back."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            size = path.stat().st_size
            if size >= 2 * len(_MAGIC) and f.read(len(_MAGIC)) == _MAGIC:
                f.seek(-len(_MAGIC), 2)
                if f.read() == _MAGIC:
                    return None
    except OSError as e:
        raise ReportError(f"{path}: cannot read: {e.strerror or e}") from None
    salvage: dict = {}
    snapshots, last, duration, named = 0, None, None, False
    for topic, _t, d in _messages(path, [TOPIC_SCENARIO, TOPIC_SNAPSHOT], None, salvage):
        if topic == TOPIC_SCENARIO:
            named = True
            duration = d.get("duration") if isinstance(d.get("duration"), (int, float)) else None
        elif isinstance(d.get("t"), (int, float)):
            snapshots += 1
            last = float(d["t"]) if last is None else max(last, float(d["t"]))
    found = Recovery(snapshots, last, duration, salvage.get("bytes_read", 0), salvage.get("size", 0))
    if not named or not snapshots:
        raise ReportError(f"{path}: {found.message()}")
    return found


def fault_marks(path, scn: Scenario | None = None) -> FaultMarks:
    """The fault marks of a recording, to advance() frame by frame: its /faults events (as the run told
    them, signals included), or, for a file without a /faults channel (recorded before there was one),
    the fault schedule of its scenario."""
    path = Path(path)
    if scn is None:
        scn, _info = read_scenario(path)
    events = [_fault(path, d) for _topic, _t, d in _messages(path, [TOPIC_FAULTS])]
    if events or TOPIC_FAULTS in _channels(path) or not scn.faults:
        timeline = [(float(e["t"]), e["event"], tuple(e["robots"]), e.get("detail", "")) for e in events]
    else:
        from swarm.core.faults import timeline as fault_timeline

        timeline = fault_timeline(scn.faults, scn.n)
    return FaultMarks(scn.n, sorted(timeline, key=lambda e: e[0]))


def _channels(path: Path) -> set[str]:
    """The topics of a finished recording's channels (empty for a file without its footer)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # no footer, damage: nothing known
        return set()
    return set() if summary is None else {c.topic for c in summary.channels.values()}


def iter_frames(path, faults: bool = False) -> Iterator[Frame]:
    """Every recorded snapshot of `path`, in time order, as a Frame (numpy arrays, rows by robot id).
    faults: also each frame's fault marks (Frame.killed, hung, cut, stale_data; fault_marks() and the
    recorded statuses), at the cost of reading the statuses too."""
    path = Path(path)
    scn, _info = read_scenario(path)
    n = scn.n
    salvage: dict = {}
    frames = 0
    marks = fault_marks(path, scn) if faults else None
    stale = np.zeros(n, bool)  # the newest status of each robot counts stale neighbour states
    status_t = np.full(n, -np.inf)  # its time [s]
    topics = [TOPIC_SNAPSHOT, TOPIC_STATUS] if faults else [TOPIC_SNAPSHOT]
    for topic, _t, d in _messages(path, topics, None, salvage):
        if topic == TOPIC_STATUS:
            try:
                i, ts, count = int(d["id"]), float(d["t"]), int(d["stale"])
            except (KeyError, TypeError, ValueError) as e:
                raise ReportError(f"{path}: bad {TOPIC_STATUS} message {str(d)[:80]}: {e}") from None
            if 0 <= i < n and ts >= status_t[i]:
                stale[i], status_t[i] = count > 0, ts
            continue
        x, y, th, _v, _w, stopped, alive, frozen = _columns(path, d, n)
        try:
            t, seq = float(d["t"]), int(d["seq"])
        except (KeyError, TypeError, ValueError) as e:
            raise ReportError(f"{path}: bad {TOPIC_SNAPSHOT} message: {e}") from None
        frames += 1
        q = np.stack([x, y, th], axis=1)
        if marks is None:
            yield Frame(t, seq, q, stopped, alive, frozen)
        else:
            marks.advance(t)
            fresh = stale & (status_t >= t - STATUS_FRESH_S - 1e-9)
            yield Frame(t, seq, q, stopped, alive, frozen, marks.killed.copy(), marks.hung.copy(), marks.cut.copy(),
                        fresh)
    if salvage and not frames:
        found = Recovery(0, None, scn.duration, salvage["bytes_read"], salvage["size"])
        raise ReportError(f"{path}: {found.message()}")


def pace(frames, speed: float = 1.0, max_hz: float | None = None, clock: Callable[[], float] = time.monotonic,
         sleep: Callable[[float], object] = time.sleep) -> Iterator:
    """Yield each frame when its time comes: frame.t - t_first simulated seconds take / speed wall seconds.

    max_hz None: every frame, late ones at once (a consumer slower than the frames is never waited
    for). max_hz given (a viewer): at most max_hz frames per wall second, and a frame whose successor
    is already due is skipped, so a slow consumer stays on time; the last frame always comes.
    clock/sleep are injectable (tests; sleep may be an Event's wait to stop promptly).
    """
    if isinstance(speed, bool) or not (math.isfinite(speed) and speed > 0):
        raise ValueError(f"speed must be a number > 0, got {speed!r}")
    if max_hz is not None and not (math.isfinite(max_hz) and max_hz > 0):
        raise ValueError(f"max_hz must be a number > 0, got {max_hz!r}")
    gap = 0.0 if max_hz is None else 1.0 / max_hz
    it = iter(frames)
    f = next(it, None)
    if f is None:
        return
    t0, w0 = f.t, clock()
    shown = -math.inf  # due time of the last frame yielded
    while f is not None:
        nxt = next(it, None)
        due = w0 + (f.t - t0) / speed
        if max_hz is not None and nxt is not None:
            if clock() >= w0 + (nxt.t - t0) / speed or due < shown + gap:
                f = nxt
                continue
        left = due - clock()
        if left > 0:
            sleep(left)
        shown = due
        yield f
        f = nxt


# --------------------------------------------------------------------------- the report


def _fmt(v) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def _table(rows: list[tuple], head: tuple[str, ...]) -> str:
    out = ["<table>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    for row in rows:
        out.append("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


_CSS = """body{font-family:sans-serif;margin:1.5em;max-width:1400px}
table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:2px 8px;text-align:left}
th{background:#f0f0f0}pre{background:#f7f7f7;padding:0.5em;overflow:auto;max-height:30em}
.panels{display:flex;flex-wrap:wrap;gap:8px}.panels figure{margin:0;width:32%}.panels img{width:100%}
img.wide{width:100%}figcaption{font-size:small}.warning{background:#fff3cd;padding:0.5em}"""


def _html(run: Run, panels: list[Path], extra: list[Path]) -> str:
    from swarm.view.plots import TITLES

    scn, rec, m = run.scenario, run.recording, run.metrics
    esc = html.escape
    title = f"{scn.name}: {scn.n} robots, {len(scn.obstacles)} obstacles"
    head = [("file", esc(run.path.name)), ("source", esc(str(run.info.get("source", "?")))),
            ("fleet", esc(str(run.info.get("fleet") or "–"))), ("dt", f"{scn.dt:g} s"),
            ("duration", f"{scn.duration:g} s"), ("seed", str(scn.seed)),
            ("samples", f"{len(rec.t)} from t = {rec.t[0]:g} s to {rec.t[-1]:g} s (record_hz "
                        f"{esc(_fmt(run.info.get('record_hz')))})"),
            ("messages", esc(", ".join(f"{k} {v}" for k, v in sorted(run.counts.items()))))]
    parts = [f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{esc(title)}</title>",
             f"<style>{_CSS}</style></head><body>", f"<h1>{esc(title)}</h1>"]
    if run.recovered is not None:
        parts.append(f"<p class='warning'><b>Incomplete recording:</b> {esc(run.recovered.message())}.</p>")
    parts += [_table(head, ("run", "")), "<h2>Metrics</h2>"]
    if m is None:
        parts.append("<p>No metrics: the run ended before it wrote them.</p>")
    else:
        rows: list[tuple[str, ...]] = [
            (esc(k), f"<span title='{esc(json.dumps(v))}'>{esc(_fmt(v))}</span>", esc(json.dumps(v)))
            for k, v in m.items()]
        parts.append(_table(rows, ("metric", "value", "exact")))
        missing = [k for k in METRIC_KEYS if k not in m]
        if missing:
            parts.append(f"<p>Missing contract keys: {esc(', '.join(missing))}</p>")
    parts += _faults_html(run)
    kinds = Counter(str(e.get("kind")) for e in run.events)
    parts.append(f"<h2>Events ({len(run.events)})</h2>")
    if kinds:
        parts.append(_table([(esc(k), str(c)) for k, c in sorted(kinds.items())], ("kind", "count")))
        rows = []
        for e in run.events[:FIRST_EVENTS]:
            who = [f"robot {e['robot']}" if e.get("robot") is not None else "",
                   f"robot {e['other']}" if e.get("other") is not None else "",
                   f"obstacle {e['obstacle']}" if e.get("obstacle") is not None else ""]
            rows.append((esc(_fmt(e.get("t"))), esc(str(e.get("kind"))), esc(", ".join(w for w in who if w)),
                         esc(_fmt(e.get("distance"))), esc(str(e.get("detail", "")))))
        more = f" (the first {FIRST_EVENTS})" if len(run.events) > FIRST_EVENTS else ""
        parts.append(f"<h3>Events in time order{more}</h3>")
        parts.append(_table(rows, ("t [s]", "kind", "bodies", "distance [m]", "detail")))
    else:
        parts.append("<p>No events.</p>")
    parts.append("<h2>Fig. 2 panels</h2>")
    by_name = {p.name: p for p in panels}
    if "fig2.png" in by_name:
        parts.append("<figure><img class='wide' src='fig2.png' alt='overview of every panel'></figure>")
    parts.append("<div class='panels'>")
    for stem, (caption, _ylabel) in TITLES.items():
        if f"{stem}.png" in by_name:
            parts.append(f"<figure><a href='{stem}.png'><img src='{stem}.png' alt='{esc(caption)}'></a>"
                         f"<figcaption>{esc(caption)}</figcaption></figure>")
    parts.append("</div>")
    parts.append("<h2>Scenario</h2><p>" + " · ".join(f"<a href='{p.name}'>{esc(p.name)}</a>" for p in extra)
                 + "</p>")
    parts.append(f"<pre>{esc(_toml_of(scn))}</pre>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


# (label, key in the metrics' faults object) of the fault counters, in the order shown
FAULT_COUNTERS = (("messages dropped", "dropped"), ("messages delayed", "delayed"), ("processes killed", "killed"),
                  ("processes restarted", "restarted"), ("processes hung", "hung"), ("partitions", "partitions"),
                  ("commands held", "cmd_held"), ("watchdog stops", "watchdog_stops"),
                  ("oldest neighbour state used [s]", "max_state_age_s"))


def fault_counter_rows(metrics: dict | None) -> list[tuple[str, str, str]]:
    """(label, metrics key, value as text) of the run's fault counters (docs/metrics.md, Under faults); a
    by-class counter as its total with the classes that are not 0. Empty without a faults object."""
    counters = (metrics or {}).get("faults")
    if not isinstance(counters, dict):
        return []
    metrics = cast(dict, metrics)  # counters came from it
    rows = []
    for label, key in FAULT_COUNTERS:
        if key not in counters:
            continue
        v = counters[key]
        if isinstance(v, dict):
            total = sum(x for x in v.values() if isinstance(x, (int, float)))
            parts = ", ".join(f"{c} {x}" for c, x in v.items() if x)
            text = f"{_fmt(total)}" + (f" ({parts})" if parts else "")
        else:
            text = _fmt(v)
        rows.append((label, f"faults.{key}", text))
    if "robots_alive_at_end" in metrics:
        rows.append(("robots alive at the end", "robots_alive_at_end",
                     f"{_fmt(metrics['robots_alive_at_end'])} of {_fmt(metrics.get('robots'))}"))
    return rows


def _faults_html(run: Run) -> list[str]:
    """The Faults section: the fault counters of the final metrics and every fault event (t, event,
    robots, detail). Nothing for a run without faults."""
    rows = fault_counter_rows(run.metrics)
    if not (rows or run.faults or run.scenario.faults):
        return []
    esc = html.escape
    parts = ["<h2>Faults</h2>"]
    if rows:
        parts.append(_table([(esc(a), f"<code>{esc(b)}</code>", esc(c)) for a, b, c in rows],
                            ("counter", "metric", "value")))
    else:
        parts.append("<p>No fault counters: the run's metrics have none.</p>")
    more = f" (the first {FIRST_FAULTS})" if len(run.faults) > FIRST_FAULTS else ""
    parts.append(f"<h3>Fault events ({len(run.faults)}){more}</h3>")
    if run.faults:
        parts.append(_table([(esc(_fmt(e.get("t"))), esc(str(e.get("event"))), esc(robot_list(e.get("robots", ()))),
                              esc(str(e.get("detail", "")))) for e in run.faults[:FIRST_FAULTS]],
                            ("t [s]", "event", "robots", "detail")))
    else:
        parts.append("<p>No fault event was recorded.</p>")
    return parts


def _toml_of(scn: Scenario) -> str:
    from swarm.core import scenario_file

    return scenario_file.to_toml(scn)


def write_report(path, out_dir) -> list[Path]:
    """Write the Fig. 2 panels of a recording (swarm.view.plots.write_panels, as `swarm sim --plots`), its
    scenario.toml and metrics.json, and index.html (a one-page summary linking them). Returns the paths
    written: the panels first, then scenario.toml, metrics.json (if the run has metrics), index.html."""
    from swarm.view.plots import write_panels

    run = read_recording(path)
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ReportError(f"{out}: cannot create the report directory: {e.strerror or e}") from None
    panels = write_panels(run.recording, run.scenario, out)
    extra = [out / "scenario.toml"]
    extra[0].write_text(_toml_of(run.scenario), encoding="utf-8")
    if run.metrics is not None:
        extra.append(out / "metrics.json")
        extra[-1].write_text(json.dumps(run.metrics, indent=2) + "\n", encoding="utf-8")
    index = out / "index.html"
    index.write_text(_html(run, panels, extra), encoding="utf-8")
    return [*panels, *extra, index]

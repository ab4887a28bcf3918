"""Terminal output: a one-line progress bar (only on a terminal) and summary tables."""

from __future__ import annotations

import shutil
import sys
import threading
import time
from typing import IO, Sequence


class StatusLine:
    """A single status line redrawn in place on a terminal, or plain log lines otherwise.

    On a terminal it redraws at most `hz` times a second; elsewhere (a pipe, a CI log)
    it prints a plain line at most every `log_every` seconds, so logs stay readable. Thread-safe: a note
    may come from a bus callback (the emergency stop) while the main thread redraws.
    """

    def __init__(self, stream: IO[str] | None = None, hz: float = 10.0, log_every: float = 10.0,
                 enabled: bool = True):
        self.stream = stream or sys.stderr
        self.tty = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.enabled = enabled
        self.min_gap = 1.0 / hz if self.tty else log_every
        self.last = -1e9
        self.width = 0
        self.pending: str | None = None  # the last text not shown (too soon after the one before): close() shows it
        self._lock = threading.RLock()

    def update(self, text: str, force: bool = False) -> None:
        if not self.enabled:
            return
        with self._lock:
            self._update(text, force)

    def _update(self, text: str, force: bool) -> None:
        now = time.monotonic()
        if not force and now - self.last < self.min_gap:
            self.pending = text
            return
        self.pending = None
        self.last = now
        if self.tty:
            cols = shutil.get_terminal_size((100, 20)).columns
            text = text[: cols - 1]
            pad = max(0, self.width - len(text))
            self.stream.write("\r" + text + " " * pad)
            self.width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def note(self, text: str) -> None:
        """A line of its own (an event), printed above the status line, which is redrawn next update."""
        if not self.enabled:
            return
        with self._lock:
            if self.tty and self.width:
                self.stream.write("\r" + " " * self.width + "\r")
                self.width = 0
                self.last = -1e9
            self.stream.write(text + "\n")
            self.stream.flush()

    def clear(self) -> None:
        """Erase the status line (on a terminal), so another stream can print a line of its own;
        the status line is redrawn at the next update. An update held back is dropped: written after that line
        (a log's at close()), it would say the state before it ("running" under the run's result)."""
        self.pending = None
        if self.enabled and self.tty and self.width:
            self.stream.write("\r" + " " * self.width + "\r")
            self.stream.flush()
            self.width = 0
            self.last = -1e9

    def close(self) -> None:
        """Show the last update if it was held back (the run's final state), then end the line (on a terminal) so
        later output starts on a fresh line."""
        with self._lock:
            if self.enabled and self.pending is not None:
                self._update(self.pending, force=True)
            if self.enabled and self.tty and self.width:
                self.stream.write("\n")
                self.stream.flush()
                self.width = 0


def counted(n: int, noun: str, plural: str = "") -> str:
    """`1 obstacle`, `2 obstacles`: a count and its noun (its plural: `plural`, else the noun and s)."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"


def converged_phrase(at_s: float | None) -> str:
    """A run's convergence for a log line: `converged at 40.68 s` or `not converged`."""
    return "not converged" if at_s is None else f"converged at {at_s} s"


def bar(fraction: float, width: int = 24) -> str:
    fraction = min(max(fraction, 0.0), 1.0)
    full = int(round(fraction * width))
    return "[" + "#" * full + "." * (width - full) + "]"


def table(rows: Sequence[tuple[str, str]], title: str | None = None) -> str:
    """Two aligned columns; returns the text (with a trailing newline)."""
    key_w = max((len(k) for k, _ in rows), default=0)
    lines = [title] if title else []
    lines += [f"  {k.ljust(key_w)}  {v}" for k, v in rows]
    return "\n".join(lines) + "\n"


def cpu_counters() -> tuple[int, int]:
    """(all, stolen) CPU time of this machine so far [clock ticks], from Linux's /proc/stat; (0, 0) elsewhere."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:9]]  # user nice system idle iowait irq softirq steal
    except (OSError, ValueError):
        return 0, 0
    return (sum(v), v[7]) if len(v) == 8 else (0, 0)


def steal_pct(before: tuple[int, int], after: tuple[int, int]) -> float | None:
    """The share of this machine's CPU time its host took between two cpu_counters() [%] (a virtual
    machine's steal time: its cores ran someone else's work), or None where it is not known."""
    total = after[0] - before[0]
    return round(100.0 * (after[1] - before[1]) / total, 1) if total > 0 else None


STEAL_NOTE_PCT = 5.0  # the summary says what the host took from a run's machine from this share on


def fmt(value: object, unit: str = "", digits: int = 4) -> str:
    """A metric for humans: None as '-', floats with `digits` significant digits."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        text = f"{value:.{digits}g}"
    else:
        text = str(value)
    return f"{text} {unit}".rstrip()


def summary(m: dict, name: str, compile_s: float | None = None) -> str:
    """The end-of-run table: the contract's results, then every counter that makes this run differ
    from a clean one (or a lock-step run from swarm sim), then what the exit code will say. compile_s: the
    seconds of the wall time spent compiling the simulator's loop (a first run), said beside it."""
    from swarm.core.metrics import nondeterminism, violations

    conv = m["converged_at_s"]
    alive = m.get("robots_alive_at_end")
    if conv is None:
        conv_text = "never (not by the end of the run)" if alive != 0 else "never (no robot alive)"
    else:
        conv_text = fmt(conv, "s")
    rows = [
        ("scenario", f"{name}  ({counted(m['robots'], 'robot')}, {counted(m['obstacles'], 'obstacle')}, "
                     f"seed {m['seed']}, dt {m['dt']:g} s{', governor on' if m.get('governor') else ', governor off'})"),
        ("simulated", fmt(m["duration_s"], "s") + ("  (interrupted)" if m["interrupted"] else "")),
        ("converged at", conv_text),
        ("final errors", f"position {fmt(m['final_position_error_max_m'], 'm', 3)}, "
                         f"orientation {fmt(m['final_orientation_error_max_rad'], 'rad', 3)}"),
        ("min distance", f"robot-robot {fmt(m['min_robot_distance_m'], 'm')}, "
                         f"robot-obstacle {fmt(m['min_obstacle_distance_m'], 'm')}"),
        ("collisions", collisions_text(m)),
        ("last freeze end", fmt(m["last_freeze_end_s"], "s")),
    ]
    if conv is None and m.get("final_spread_m") is not None:  # what a law whose goal is not the slots is judged by
        rows.insert(3, ("spread at end", f"{fmt(m['final_spread_m'], 'm')} (the largest distance between two robots)"))
    if alive is not None and alive != m["robots"]:
        rows.append(("robots alive", f"{alive} of {m['robots']} at the end"))
    faults = m.get("faults") if isinstance(m.get("faults"), dict) else None
    rows += fault_rows(m) if faults is not None else []
    for key, label in (("cmd_misses", "missed commands"), ("bad_messages", "bad messages"),
                       ("messages_dropped", "messages dropped"), ("robot_restarts", "robot restarts"),
                       ("leader_restarts", "leader restarts"),
                       ("robots_lost", "robots lost"), ("lockstep_overruns", "lock-step overruns"),
                       ("launcher_bad_messages", "bad messages (launcher)")):
        if m.get(key) and not (faults is not None and key == "messages_dropped"):
            rows.append((label, str(m[key])))
    if m.get("mode") == "realtime" and (m.get("round_trip_ms_p99") is not None or m.get("held_back") is not None):
        rows.append(("real time", realtime_text(m)))
    for line in m.get("stranded_detail") or ():
        rows.append(("stranded", str(line)))
    stop = estop_text(m)
    if stop:
        rows.append(("emergency stop", stop))
    if m.get("samples_missed"):  # real time: the world fell behind its control periods
        rows.append(("world behind", f"{m['samples_missed']} control period{'s' if m['samples_missed'] != 1 else ''} not sampled (of "
                                     f"{m['samples_missed'] + m.get('samples', 0)}): the machine could not keep "
                                     "up; try a lower --speed"))
    nd = nondeterminism(m)
    if nd:
        rows.append(("lock-step", f"NOT deterministic: {', '.join(nd)}; this run may differ from swarm sim "
                                  "(docs/runtime.md)"))
    if m.get("failure"):
        rows.append(("FAILED", str(m["failure"])))
    v = violations(m)
    if v:
        rows.append(("CHECKS FAILED", ", ".join(v)))
    wall = fmt(m["wall_s"], "s", 3)
    run = m.get("run_wall_s")
    if m.get("mode") == "lockstep" and isinstance(run, (int, float)) and run > 0 and m.get("duration_s"):
        wall += f"  (the run {run:.1f} s of it: {m['duration_s'] / run:.2f} simulated s a wall s)"
    if compile_s:
        wall += f"  ({compile_s:.1f} s of it compiling the loop, once: later runs load it from numba's cache)"
    stolen = m.get("host_steal_pct")
    if isinstance(stolen, (int, float)) and stolen >= STEAL_NOTE_PCT:
        wall += f"  (the host took {stolen:g} % of this machine's CPU meanwhile: a slow run may be its, not swarm's)"
    rows.append(("wall time", wall))
    return table(rows, "summary")


def collisions_text(m: dict) -> str:
    """The collision count, with the hint a collision of the paper's law without the governor calls for: its
    guarantee is for continuous time, and a robot can cross a neighbour's ring between two control steps."""
    n = m["collisions"]
    if not n or m.get("governor"):
        return str(n)
    return (f"{n}  (the safety governor was off, as in the paper: its law keeps robots apart in continuous time, "
            "and a control step can jump a robot through a neighbour's stiff wall; --governor limits each step's "
            "speed so no clearance is crossed: docs/design.md, The safety governor)")


def estop_text(m: dict) -> str | None:
    """The emergency stop as the world saw it (metrics `estops`): each change with its time and reason; None when
    it was never engaged."""
    e = m.get("estops")
    if not isinstance(e, dict) or not e.get("engaged"):
        return None
    said = []
    for ev in e.get("events") or ():
        if isinstance(ev, dict):
            what = "engaged" if ev.get("engaged") else "released"
            said.append(f"{what} at t = {fmt(ev.get('t'), 's')}" +
                        (f" ({printable(str(ev['reason']))})" if ev.get("reason") else ""))
    text = ", ".join(said[:6]) + (f", and {len(said) - 6} more" if len(said) > 6 else "")
    if e.get("engaged", 0) > e.get("released", 0):
        text += "; still ENGAGED at the end"
    return text


SLOW_ROUND_TRIP_MS = 100.0  # a real-time round trip p99 from which the summary names the likely cause


def realtime_text(m: dict) -> str:
    """How a real-time run held up: the control round trip's p99 and how often the robots' safety rule held them
    back, then the commands the world braked (they ran out) or refused (they came after their validity); with a
    p99 of SLOW_ROUND_TRIP_MS or more that the run's faults did not delay on purpose, the usual cause."""
    parts = []
    p99, held = m.get("round_trip_ms_p99"), m.get("held_back")
    if isinstance(p99, (int, float)):
        parts.append(f"round trip p99 {p99:.0f} ms")
    if isinstance(held, (int, float)):
        parts.append(f"robots held back {100 * held:.1f} % of the time")
    text = ": ".join(parts)
    late = [f"{counted(m[k], 'command')} {what}" for k, what in (("cmd_braked", "ran out (braked)"),
                                                                 ("cmd_expired", "came too late")) if m.get(k)]
    text += f"; {', '.join(late)}" if late else ""
    faults = m.get("faults")
    delayed = faults.get("delayed") if isinstance(faults, dict) else None
    if isinstance(p99, (int, float)) and p99 >= SLOW_ROUND_TRIP_MS and not (isinstance(delayed, dict)
                                                                           and any(delayed.values())):
        text += ("  (a slow round trip: a machine short of CPU for its robots, see `world behind` and the start's "
                 "capacity warning; or a link that loses packets, where TCP holds every message behind a lost one "
                 "until it sends it again, 200 ms at least with Linux's default: lower that minimum on every "
                 "machine, docs/deploy.md, Lossy links)")
    return text


def _by_class(counts: object) -> str:
    """{"state": 3, "pose": 0, ...} as "3 (state 3)": the total, then the classes that are not 0."""
    if not isinstance(counts, dict):
        return fmt(counts)
    total = sum(v for v in counts.values() if isinstance(v, (int, float)))
    parts = ", ".join(f"{c} {v}" for c, v in counts.items() if v)
    return f"{total}" + (f" ({parts})" if parts else "")


def fault_rows(m: dict) -> list[tuple[str, str]]:
    """The summary's rows of a run with faults (the metrics' `faults` object, docs/metrics.md): the process
    faults and partitions that happened, the messages dropped (and delayed) by class, what the world did
    about the missing commands, and the oldest neighbour state a law used."""
    f = m["faults"]
    rows = [("faults", ", ".join(f"{label} {f.get(key, 0)}" for key, label in (
        ("killed", "killed"), ("restarted", "restarted"), ("hung", "hung"), ("partitions", "partitions"))))]
    rows.append(("messages dropped", _by_class(f.get("dropped", m.get("messages_dropped", 0)))))
    delayed = f.get("delayed")
    if isinstance(delayed, dict) and any(delayed.values()):
        rows.append(("messages delayed", _by_class(delayed)))
    if f.get("cmd_held") or f.get("watchdog_stops"):
        rows.append(("world", f"commands held {f.get('cmd_held', 0)}, watchdog stops {f.get('watchdog_stops', 0)}"))
    if f.get("max_state_age_s"):
        rows.append(("oldest state used", fmt(f["max_state_age_s"], "s", 3)))
    return rows


def exit_status(m: dict, allow_violations: bool = False) -> int:
    """The exit code of a finished command from its metrics: 130 interrupted, 1 a failure, 3 a check
    failed (unless allow_violations), else 0."""
    from swarm.core.metrics import violations

    if m.get("interrupted"):
        return 130
    if m.get("failure"):
        return 1
    if violations(m) and not allow_violations:
        return 3
    return 0


def fault_fields(dropped: int = 0, dead: int = 0, hung: int = 0) -> str:
    """The status line's fault counts, each only when not 0 ("" in a run without faults): messages the
    fault schedule dropped so far, robots dead, robots hung now; with two leading spaces."""
    return "".join(f"  {name} {n}" for name, n in (("dropped", dropped), ("dead", dead), ("hung", hung)) if n)


def printable(text: str, keep: str = "") -> str:
    """Text from the network, safe on a terminal: every character that is not printable (controls such as ESC,
    which could retitle the terminal, erase lines or fake a row; bidirectional overrides; line breaks) written
    as its escape (\\x1b), the rest as it is, and the characters of `keep`."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() or c in keep else c.encode("unicode_escape").decode("ascii") for c in text)


class EstopFollower:
    """`swarm up`'s view of the emergency stop: the world's estop and estop_release events (world/events), each said
    once (a line above the status line) and `engaged` (its reason) while in force, for the status line."""

    def __init__(self, bus, fleet: str, say) -> None:
        from swarm.proto import keys

        self.engaged: str | None = None
        self._say = say
        self._handle = bus.subscribe(keys.world_events(fleet), self._on)

    def _on(self, key: str, payload: bytes) -> None:
        from swarm.proto import protocol

        try:
            e = protocol.decode(payload, "event")
        except protocol.ProtocolError:
            return  # the world's events are the recorder's to count; this only follows the stop
        if e.event == "estop":
            self.engaged = printable(e.detail) or "no reason given"
            self._say(f"emergency stop ENGAGED at t = {e.t:.2f} s: {self.engaged}")
        elif e.event == "estop_release":
            self.engaged = None
            self._say(f"emergency stop released at t = {e.t:.2f} s")


def progress_line(p, estop: str | None = None) -> str:
    """The status line of `swarm up` from the world's progress message (swarm.proto.protocol.Progress):
    time, robots alive, then the faults' counts when there are any (dropped messages, dead and hung
    robots: fault_fields), converged, frozen, the smallest distance, missed commands, bad messages; and
    E-STOP with its reason while the emergency stop is engaged."""
    dist = "-" if p.min_distance < 0 else f"{p.min_distance:.3f} m"
    faults = fault_fields(getattr(p, "dropped", 0), max(0, p.robots - p.alive), getattr(p, "hung", 0))
    held = getattr(p, "held", -1.0)
    extra = (f"  held {100 * held:.0f}%" if held >= 0 else "") + \
        (f"  stranded {p.stranded}" if getattr(p, "stranded", 0) else "") + \
        (f"  E-STOP ({estop})" if estop is not None else "")
    return (f"{bar(p.t / p.duration if p.duration else 1)} t {p.t:7.2f}/{p.duration:.1f} s"
            f"  alive {p.alive}/{p.robots}{faults}  converged {p.converged}  frozen {p.frozen}  min distance {dist}"
            f"  misses {p.misses}  bad {p.bad}{extra}")

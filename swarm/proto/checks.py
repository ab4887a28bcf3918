"""What decode() holds a message to: each field's type as it is read (numbers finite, ints in range, strings
bounded, the exact set of fields), each kind's physical bounds (_CHECK), a scenario's bounds (Limits), and the
nested kinds (obstacles, bodies, event, snapshot) read and checked row by row. Every refusal is a ProtocolError
that says what was wrong."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from swarm.proto.messages import (Bodies, Body, Claim, Clock, Cmd, Config, EVENTS, Event, FaultStats, Obstacle,
                                  Obstacles, Pose, Proc, ProtocolError, Ref, RobotSnap, Run, Snapshot, State, Status)
from swarm.proto.spec import (MAX_ANGLE, MAX_COORD, MAX_LARGE_PAYLOAD, MAX_LAW_MEMORY, MAX_LAW_PARAMS, MAX_ROBOTS,
                              MAX_SPEED, MAX_TEXT, MAX_TIME, MAX_TURN, _OPTIONAL, _SNAP_FIELDS, _SPEC, _WIRE)

if TYPE_CHECKING:
    from collections.abc import Callable
    from typing import Any


def _num(d: dict[str, Any], name: str) -> float:
    x = d[name]
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise ProtocolError(f"field {name!r} must be a number, got {type(x).__name__}")
    x = float(x)
    if not math.isfinite(x):
        raise ProtocolError(f"field {name!r} must be finite, got {x}")
    return x


def _int(d: dict[str, Any], name: str, limit: int = 2**53) -> int:
    x = d[name]
    if isinstance(x, bool) or not isinstance(x, int):
        raise ProtocolError(f"field {name!r} must be an integer, got {type(x).__name__}")
    if not 0 <= x <= limit:
        raise ProtocolError(f"field {name!r} must be in [0, {limit}], got {x}")
    return x


def _text(d: dict[str, Any], name: str, limit: int = MAX_TEXT) -> str:
    x = d[name]
    if not isinstance(x, str):
        raise ProtocolError(f"field {name!r} must be a string, got {type(x).__name__}")
    if len(x) > limit:
        raise ProtocolError(f"field {name!r} must be at most {limit} characters, got {len(x)}")
    return x


def _bool(d: dict[str, Any], name: str) -> bool:
    x = d[name]
    if not isinstance(x, bool):
        raise ProtocolError(f"field {name!r} must be true or false, got {type(x).__name__}")
    return x


def _radii(r: float, R: float) -> None:
    if not (0 < r < R):
        raise ProtocolError(f"radii must satisfy 0 < r < R, got r = {r}, R = {R}")


def _fields(d: dict[str, Any], names: tuple[str, ...]) -> None:
    missing = [n for n in names if n not in d]
    if missing:
        raise ProtocolError(f"missing field(s) {', '.join(missing)}")
    extra = [str(n) for n in d if n not in names and n not in ("v", "kind")]
    if extra:
        raise ProtocolError(f"unknown field(s) {', '.join(sorted(extra))[:80]}")


def _spec_fields(d: dict[str, Any], kind: str) -> None:
    """_fields for a flat kind: every field of its spec but its optional ones (_OPTIONAL), nothing else."""
    optional = _OPTIONAL.get(kind, ())
    _fields(d, tuple(n for n, _ in _SPEC[kind] if n not in optional or n in d))


def _floats(d: dict[str, Any], name: str) -> tuple[float, ...]:
    x = d[name]
    if not isinstance(x, list) or len(x) > MAX_LAW_PARAMS:
        raise ProtocolError(f"field {name!r} must be a list of at most {MAX_LAW_PARAMS} numbers")
    return tuple(_num({name: v}, name) for v in x)


_READ: dict[str, Callable[[dict[str, Any], str], Any]] = {
    "f": _floats, "n": _num, "i": _int, "b": _bool, "id": lambda d, n: _int(d, n, MAX_ROBOTS - 1), "s": _text,
    "S": lambda d, n: _text(d, n, MAX_LARGE_PAYLOAD)}


def _positive(msg: object, *names: str) -> None:
    for name in names:
        if not getattr(msg, name) > 0:
            raise ProtocolError(f"field {name!r} must be > 0, got {getattr(msg, name)}")


def _nonnegative(msg: object, *names: str) -> None:
    for name in names:
        if not getattr(msg, name) >= 0:
            raise ProtocolError(f"field {name!r} must be >= 0, got {getattr(msg, name)}")


def _check_config(c: Config) -> None:
    _radii(c.r, c.R)
    _positive(c, "k1", "k2", "k3", "tu", "dt", "sense", "v_bound")
    _nonnegative(c, "vt")
    if c.threshold not in (0, 1, 2):
        raise ProtocolError(f"field 'threshold' must be 0, 1 or 2, got {c.threshold}")
    if not c.R <= c.reach < c.sense:
        raise ProtocolError(f"fields must hold R <= reach < sense, got R {c.R}, reach {c.reach}, sense {c.sense}")
    given = [c.law is not None, c.law_sha256 is not None, c.law_params is not None, c.law_memory is not None]
    if any(given) and not all(given):
        raise ProtocolError("fields law, law_sha256, law_params and law_memory come all four or none")
    if c.law_sha256 is not None and not (len(c.law_sha256) == 64 and all(ch in "0123456789abcdef" for ch in c.law_sha256)):
        raise ProtocolError("field 'law_sha256' must be 64 lowercase hexadecimal digits")
    if c.law is not None:
        where, _, name = c.law.rpartition(":")
        if not (name.isidentifier() and (where.endswith(".py") or
                                         (where and all(part.isidentifier() for part in where.split("."))))):
            raise ProtocolError("field 'law' must read FILE.py:NAME or package.module:NAME")
    if c.law_memory is not None and c.law_memory > MAX_LAW_MEMORY:
        raise ProtocolError(f"field 'law_memory' must be at most {MAX_LAW_MEMORY}, got {c.law_memory}")


def _within(msg: object, limit: float, *names: str) -> None:
    """|field| <= limit for each named field (physical bounds: a finite but absurd value is refused)."""
    for name in names:
        x = getattr(msg, name)
        if not -limit <= x <= limit:
            raise ProtocolError(f"field {_WIRE.get(name, name)!r} must be within +-{limit:g}, got {x:g}")


def _check_ref(m: Ref) -> None:
    _within(m, MAX_TIME, "t")
    _within(m, MAX_COORD, "x", "y")
    _within(m, MAX_ANGLE, "theta")
    _within(m, MAX_SPEED, "v")
    _within(m, MAX_TURN, "w")


def _check_pose(m: Pose | State) -> None:
    _within(m, MAX_TIME, "t")
    _within(m, MAX_COORD, "x", "y")
    _within(m, MAX_ANGLE, "theta")
    if getattr(m, "cmd", None) is not None:  # (a state is checked as a pose too: it has no such field)
        _within(m, MAX_TIME, "cmd")


def _check_cmd(m: Cmd) -> None:
    _within(m, MAX_TIME, "t")
    _within(m, MAX_SPEED, "v")
    _within(m, MAX_TURN, "w")
    if m.until is not None:
        _within(m, MAX_TIME, "until")


def _check_state(m: State) -> None:
    _radii(m.r, m.R)
    _within(m, MAX_COORD, "R")
    _check_pose(m)
    if m.stop is not None:
        _within(m, MAX_COORD, "stop")
        _nonnegative(m, "stop")
    if m.still is not None:
        _within(m, MAX_TIME, "still")


def _check_status(m: Status) -> None:
    _within(m, MAX_TIME, "t")
    _within(m, 2 * MAX_COORD, "ex", "ey")
    _within(m, MAX_ANGLE, "etheta")
    if m.held is not None and not 0.0 <= m.held <= 1.0:
        raise ProtocolError(f"field 'held' must be in [0, 1], got {m.held:g}")


def _check_clock(m: Clock) -> None:
    _positive(m, "speed")
    _nonnegative(m, "epoch")
    _within(m, MAX_TIME, "t")
    _within(m, 1e6, "speed")
    _within(m, 1e11, "epoch")


def _check_config_bounds(c: Config) -> None:
    _check_config(c)
    _within(c, MAX_COORD, "x", "y", "dx", "dy", "R", "sense", "xmin", "xmax", "ymin", "ymax")
    if c.arena and not (c.xmin < c.xmax and c.ymin < c.ymax):
        raise ProtocolError(f"an arena must have xmin < xmax and ymin < ymax, got {(c.xmin, c.xmax, c.ymin, c.ymax)}")
    _within(c, MAX_ANGLE, "theta")
    _within(c, MAX_SPEED, "v_max", "v_bound")
    _within(c, MAX_TURN, "w_max")
    _nonnegative(c, "v_max", "w_max")
    if not 1 <= c.robots <= MAX_ROBOTS or c.id >= c.robots:
        raise ProtocolError(f"fields must hold 1 <= robots <= {MAX_ROBOTS} and id < robots, "
                            f"got id {c.id}, robots {c.robots}")


def _check_run(m: Run) -> None:
    if not 1 <= m.robots <= MAX_ROBOTS:
        raise ProtocolError(f"field 'robots' must be in 1..{MAX_ROBOTS}, got {m.robots}")
    if not m.run:
        raise ProtocolError("field 'run' must not be empty")


def _check_claim(m: Claim) -> None:
    if not 1 <= m.robots <= MAX_ROBOTS:
        raise ProtocolError(f"field 'robots' must be in 1..{MAX_ROBOTS}, got {m.robots}")
    if m.granted and m.id >= m.robots:
        raise ProtocolError(f"a granted id must be below robots, got id {m.id}, robots {m.robots}")
    if not m.claim:
        raise ProtocolError("field 'claim' must not be empty")


def _check_faultstats(m: FaultStats) -> None:
    _within(m, MAX_TIME, "t", "max_age")
    _nonnegative(m, "max_age")


def _check_proc(m: Proc) -> None:
    if m.role not in PROC_ROLES:
        raise ProtocolError(f"field 'role' must be one of {', '.join(PROC_ROLES)}, got {m.role!r}")
    if m.pid <= 0:
        raise ProtocolError(f"field 'pid' must be a process id (> 0), got {m.pid}")
    _within(m, 1e11, "started")


PROC_ROLES = ("router", "world", "leader", "robot", "viz", "recorder", "launcher")  # keys.ROLES


_CHECK: dict[str | None, Callable[[Any], None]] = {  # looked up with an expected kind, which may be None
    "claim": _check_claim,
    "proc": _check_proc,
    "ref": _check_ref,
    "pose": _check_pose,
    "cmd": _check_cmd,
    "state": _check_state,
    "status": _check_status,
    "config": _check_config_bounds,
    "clock": _check_clock,
    "progress": lambda m: _within(m, MAX_TIME, "t", "duration"),
    "run": _check_run,
    "estop": lambda m: _within(m, 1e11, "t"),
    "faultstats": _check_faultstats,
}


@dataclass(frozen=True)
class Limits:
    """A scenario's bounds on incoming messages, on top of the physical ones: robot ids below
    `robots`, radii at most `radius` (the largest R of any body), commands within the speed bounds,
    positions inside `bounds` (the arena grown by a margin; None: only |x|, |y| <= MAX_COORD)."""

    robots: int
    radius: float
    v_max: float = MAX_SPEED
    w_max: float = MAX_TURN
    bounds: tuple[float, float, float, float] | None = None

    @classmethod
    def of(cls, robots: int, radius: float, v_max: float | None = None, w_max: float | None = None,
           arena: tuple[float, float, float, float] | None = None, margin: float = 0.0) -> "Limits":
        """From a scenario's numbers (v_max/w_max None or 0: only the physical bounds); arena grown by margin [m]."""
        bounds = None
        if arena is not None:
            xmin, xmax, ymin, ymax = arena
            bounds = (xmin - margin, xmax + margin, ymin - margin, ymax + margin)
        return cls(robots, radius, v_max or MAX_SPEED, w_max or MAX_TURN, bounds)

    def check(self, msg: object) -> None:
        tol = 1 + 1e-9
        if isinstance(msg, (State, RobotSnap)) and msg.id >= self.robots:
            raise ProtocolError(f"robot id {msg.id} is not in the scenario ({self.robots} robots)")
        if isinstance(msg, State) and msg.R > self.radius * tol:
            raise ProtocolError(f"radius R = {msg.R:g} exceeds the scenario's largest R = {self.radius:g}")
        if isinstance(msg, Cmd) and (abs(msg.v) > self.v_max * tol or abs(msg.w) > self.w_max * tol):
            raise ProtocolError(f"command (vel {msg.v:g}, w {msg.w:g}) beyond the scenario's speed bounds "
                                f"({self.v_max:g} m/s, {self.w_max:g} rad/s)")
        if self.bounds is not None and isinstance(msg, (Pose, State)):
            xmin, xmax, ymin, ymax = self.bounds
            if not (xmin <= msg.x <= xmax and ymin <= msg.y <= ymax):
                raise ProtocolError(f"position ({msg.x:g}, {msg.y:g}) outside the arena {self.bounds}")
        if isinstance(msg, Snapshot):
            for s in msg.robots:
                self.check(s)


def _item(row: object, where: str, names: tuple[str, ...]) -> dict[str, Any]:
    if not isinstance(row, dict):
        raise ProtocolError(f"{where} must be a map of {', '.join(names)}")
    try:
        _fields(row, names)
    except ProtocolError as e:
        raise ProtocolError(f"{where}: {e}") from None
    return row


def _obstacles(d: dict[str, Any]) -> Obstacles:
    _fields(d, ("obstacles",))
    rows = d["obstacles"]
    if not isinstance(rows, list) or len(rows) > MAX_ROBOTS:
        raise ProtocolError("field 'obstacles' must be a list of {x, y, r, R}")
    out = []
    for i, row in enumerate(rows):
        o = _item(row, f"obstacles[{i}]", ("x", "y", "r", "R"))
        ob = Obstacle(_num(o, "x"), _num(o, "y"), _num(o, "r"), _num(o, "R"))
        _radii(ob.r, ob.R)
        _within(ob, MAX_COORD, "x", "y", "R")
        out.append(ob)
    return Obstacles(tuple(out))


def _event(d: dict[str, Any]) -> Event:
    _fields(d, ("t", "seq", "event", "robots", "detail"))
    rows = d["robots"]
    if not isinstance(rows, list) or len(rows) > MAX_ROBOTS:
        raise ProtocolError("field 'robots' must be a list of robot ids")
    robots = tuple(_int({"robots[]": r}, "robots[]", MAX_ROBOTS - 1) for r in rows)
    msg = Event(_num(d, "t"), _int(d, "seq"), _text(d, "event"), robots, _text(d, "detail"))
    if msg.event not in EVENTS:
        raise ProtocolError(f"field 'event' must be one of {', '.join(EVENTS)}, got {msg.event[:40]!r}")
    _within(msg, MAX_TIME, "t")
    return msg


def _bodies(d: dict[str, Any]) -> Bodies:
    _fields(d, ("t", "seq", "bodies", "returning"))

    def rows_of(name: str) -> tuple[Body, ...]:
        rows = d[name]
        if not isinstance(rows, list) or len(rows) > MAX_ROBOTS:
            raise ProtocolError(f"field {name!r} must be a list of {{id, x, y, r, R}}")
        out = []
        for i, row in enumerate(rows):
            b = _item(row, f"{name}[{i}]", ("id", "x", "y", "r", "R"))
            body = Body(_int(b, "id", MAX_ROBOTS - 1), _num(b, "x"), _num(b, "y"), _num(b, "r"), _num(b, "R"))
            _radii(body.r, body.R)
            _within(body, MAX_COORD, "x", "y", "R")
            out.append(body)
        return tuple(out)

    msg = Bodies(_num(d, "t"), _int(d, "seq"), rows_of("bodies"), rows_of("returning"))
    _within(msg, MAX_TIME, "t")
    return msg


def _snapshot(d: dict[str, Any]) -> Snapshot:
    _fields(d, ("t", "seq", "robots"))
    rows = d["robots"]
    if not isinstance(rows, list) or len(rows) > MAX_ROBOTS:
        raise ProtocolError("field 'robots' must be a list")
    out = []
    for i, row in enumerate(rows):
        r = _item(row, f"robots[{i}]", _SNAP_FIELDS)
        s = RobotSnap(_int(r, "id", MAX_ROBOTS - 1), _num(r, "x"), _num(r, "y"), _num(r, "theta"),
                      _num(r, "v"), _num(r, "w"), _bool(r, "stopped"), _bool(r, "alive"))
        _within(s, MAX_COORD, "x", "y")
        _within(s, MAX_ANGLE, "theta")
        _within(s, MAX_SPEED, "v")
        _within(s, MAX_TURN, "w")
        out.append(s)
    snap = Snapshot(_num(d, "t"), _int(d, "seq"), tuple(out))
    _within(snap, MAX_TIME, "t")
    return snap

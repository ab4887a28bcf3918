"""The fault model (docs/faults.md): faults as data, checked once, and the schedule every process reads.

    parse_faults(doc["faults"], "my.toml", robots=37, duration=120.0, default_seed=0) -> Faults
    load_faults_file("faults.toml", 37, 120.0, 0)                                 -> Faults  (--faults FILE)
    merged(faults, drops=(drop_shorthand(0.1),), kills=kill_shorthand("2@5", 37, 120.0))   (--drop, --kill)
    to_toml(faults)                                  -> the canonical [faults] text (part of the run's digest)
    swarm.core.faulttable.FaultTable.of(faults, robots, dt)   -> numpy arrays for swarm.core.faultgen's decisions

A `[faults]` table holds message rules (drop, delay: per link and class, in a time window),
partitions (groups of robots that hear nothing from one another for a window) and process faults
(kill with an optional restart, hang). Every key is checked like the scenario contract: a refusal is
a ScenarioError naming the file, the key and the reason. Whether a message is lost or late is
decided by swarm.core.faultgen, a pure function of (seed, rule, class, sender, receiver, k), so the
simulator and every process decide alike, in any order.

Ids: robots 0..N-1; WORLD (-1) and LEADER (-2) as the world and the leader on links. A state
message from robot j to robot i is link (j, i), a pose to robot i (WORLD, i), a command of robot i
(i, WORLD), a reference to robot i (LEADER, i). A `from` / `to` list names robots only: it never
matches the world or the leader.

Times are simulated seconds; a window is [start, end) of the message's send time, a bound within
faultgen.TIME_EPS of t counting as t itself (the tick k dt that rounding puts just below it is in).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any, Callable, TypeVar, cast

import numpy as np

from swarm.core import faultgen as fg
from swarm.core.errors import ScenarioError
from swarm.core.toml_reader import Reader, kind, read_toml
from swarm.core.errors import SwarmError

CLASSES = {"state": fg.CLS_STATE, "pose": fg.CLS_POSE, "cmd": fg.CLS_CMD, "ref": fg.CLS_REF, "all": fg.CLS_ALL}
WORLD = fg.WORLD
LEADER = fg.LEADER
KINDS = ("kill", "restart", "hang", "resume")  # process events; at one instant ends come before starts
_KIND_ORDER = {"restart": 0, "resume": 1, "kill": 2, "hang": 3}
PROCESS_STATES = ("alive", "dead", "hung")  # indexed by faultgen.PROC_*

# Bounds that keep the numeric table small and decisions cheap (each message reads every rule).
MAX_RULES = 64  # drop rules, and as many delay rules
MAX_PARTITIONS = 16
MAX_PROCESS_FAULTS = 10_000  # kills and hangs together
MAX_DELAY_TICKS = 1_000_000  # ticks + jitter of one rule
SEED_LIMIT = 1 << 63  # a seed is a non-negative int64

_T = TypeVar("_T")


class FaultError(SwarmError, ValueError):
    """A fault value that makes no sense; `field` is its key relative to its rule (or to [faults])."""

    def __init__(self, field: str, reason: str):
        self.field, self.reason = field, reason
        super().__init__(f"{field}: {reason}")


def _time(value: float, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise FaultError(field, f"must be a finite number of seconds, got {value!r}")
    if value < 0:
        raise FaultError(field, f"must be >= 0 s (times count from the start of the run), got {value!r}")
    return float(value)


def _window(start: float, end: float) -> tuple[float, float]:
    start = _time(start, "start")
    if isinstance(end, bool) or not isinstance(end, (int, float)) or math.isnan(end) or end == -math.inf:
        raise FaultError("end", f"must be a number of seconds, got {end!r}")
    if not end >= start:  # end == start: an empty window, accepted (advisories() says it never acts)
        raise FaultError("end", f"must not be before start = {start:g} s (a window [start, end)), got {end:g}")
    return start, float(end)


def _ids(value: tuple[int, ...] | None, field: str) -> tuple[int, ...] | None:
    if value is None:
        return None
    ids = tuple(value)
    if not ids:
        raise FaultError(field, "lists no robot (leave the key out for every robot)")
    seen: set[int] = set()
    for k, i in enumerate(ids):
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or i < 0:
            raise FaultError(f"{field}[{k}]", f"must be a robot id (an integer >= 0), got {i!r}")
        seen.add(int(i))  # a robot listed twice is listed once
    return tuple(sorted(seen))


def _class_ends(cls: str, senders: tuple[int, ...] | None, receivers: tuple[int, ...] | None) -> None:
    if not isinstance(cls, str) or cls not in CLASSES:
        raise FaultError("class", f"must be one of {', '.join(repr(c) for c in CLASSES)}, got {cls!r}")


def _matches_nothing(cls: str, senders: tuple[int, ...] | None, receivers: tuple[int, ...] | None) -> str | None:
    """Why a rule's links are none (a pose or ref has no robot sender, a cmd no robot receiver), or None."""
    if senders is not None and cls in ("pose", "ref"):
        return f"a {cls} is sent by the {'world' if cls == 'pose' else 'leader'}, never by a robot, and it names 'from'"
    if receivers is not None and cls == "cmd":
        return "a cmd goes to the world, never to a robot, and it names 'to'"
    return None


@dataclass(frozen=True)
class DropRule:
    """Lose messages of class `cls` with stationary probability p, in bursts of mean length `burst`
    messages (1: independent losses), on links whose sender is in `senders` and receiver in
    `receivers` (None: any, the world and the leader included), sent in [start, end) s."""

    cls: str
    p: float
    burst: float = 1.0
    senders: tuple[int, ...] | None = None
    receivers: tuple[int, ...] | None = None
    start: float = 0.0
    end: float = math.inf
    burst_given: float | None = field(default=None, compare=False, repr=False)  # a burst too short for p, raised

    def __post_init__(self) -> None:
        for name in ("p", "burst"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise FaultError(name, f"must be a finite number, got {v!r}")
        if not 0.0 <= self.p <= 1.0:
            raise FaultError("p", f"must be a probability, 0 <= p <= 1, got {self.p:g}")
        if not self.burst >= 1.0:
            raise FaultError("burst", f"must be >= 1 (a mean number of messages; 1: independent losses), got {self.burst:g}")
        if self.burst > 1.0 and 0.0 < self.p < 1.0 and self.p > self.burst / (self.burst + 1.0):
            # bursts of mean length b lose at most b / (b + 1) of the messages (a delivered message separates two
            # bursts): p is kept, and the bursts are the shortest that lose it (advisories() says so)
            object.__setattr__(self, "burst_given", float(self.burst))
            object.__setattr__(self, "burst", self.p / (1.0 - self.p))
        senders, receivers = _ids(self.senders, "from"), _ids(self.receivers, "to")
        _class_ends(self.cls, senders, receivers)
        start, end = _window(self.start, self.end)
        for name, v in (("p", float(self.p)), ("burst", float(self.burst)), ("senders", senders),
                        ("receivers", receivers), ("start", start), ("end", end)):
            object.__setattr__(self, name, v)


@dataclass(frozen=True)
class DelayRule:
    """Deliver messages of class `cls` `ticks` control periods late, plus a whole number uniform in
    0..jitter (messages then reorder); same link and window selection as DropRule."""

    cls: str
    ticks: int
    jitter: int = 0
    senders: tuple[int, ...] | None = None
    receivers: tuple[int, ...] | None = None
    start: float = 0.0
    end: float = math.inf

    def __post_init__(self) -> None:
        for name in ("ticks", "jitter"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise FaultError(name, f"must be a whole number of control periods, got {v!r}")
            if v < 0:
                raise FaultError(name, f"must be >= 0, got {v}")
        if self.ticks + self.jitter > MAX_DELAY_TICKS:
            raise FaultError("jitter" if self.jitter else "ticks", f"ticks + jitter = {self.ticks + self.jitter}: "
                             f"a message is at most {MAX_DELAY_TICKS} control periods late")
        senders, receivers = _ids(self.senders, "from"), _ids(self.receivers, "to")
        _class_ends(self.cls, senders, receivers)
        start, end = _window(self.start, self.end)
        for name, v in (("ticks", int(self.ticks)), ("jitter", int(self.jitter)), ("senders", senders),
                        ("receivers", receivers), ("start", start), ("end", end)):
            object.__setattr__(self, name, v)


@dataclass(frozen=True)
class Partition:
    """During [start, end) nothing crosses between the groups (robot ids; the robots in no group form
    one more group; the world and the leader are in the first group)."""

    groups: tuple[tuple[int, ...], ...]
    start: float = 0.0
    end: float = math.inf

    def __post_init__(self) -> None:
        if not isinstance(self.groups, (tuple, list)) or not self.groups:
            raise FaultError("groups", f"must be a non-empty list of groups of robot ids, got {self.groups!r}")
        seen: dict[int, int] = {}
        groups = []
        for g, group in enumerate(self.groups):
            if not isinstance(group, (tuple, list)):
                raise FaultError(f"groups[{g}]", f"must be a list of robot ids, got {group!r}")
            if not group:
                raise FaultError(f"groups[{g}]", "is empty (a group holds at least one robot)")
            for k, i in enumerate(group):
                if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or i < 0:
                    raise FaultError(f"groups[{g}][{k}]", f"must be a robot id (an integer >= 0), got {i!r}")
                if int(i) in seen:
                    where = "this group" if seen[int(i)] == g else f"groups[{seen[int(i)]}]"
                    raise FaultError(f"groups[{g}][{k}]", f"robot {i} is already in {where} (a robot is in one group)")
                seen[int(i)] = g
            groups.append(tuple(sorted(int(i) for i in group)))
        start, end = _window(self.start, self.end)
        for name, v in (("groups", tuple(groups)), ("start", start), ("end", end)):
            object.__setattr__(self, name, v)

    def group(self, robot: int) -> int:
        """The group of a robot id during the window (len(groups): the robots in no group)."""
        for g, group in enumerate(self.groups):
            if robot in group:
                return g
        return len(self.groups)


@dataclass(frozen=True)
class Kill:
    """SIGKILL robot's process at `at` s; with `restart`, a new process takes the robot over that many
    seconds later (None: it stays dead)."""

    robot: int
    at: float
    restart: float | None = None

    def __post_init__(self) -> None:
        _robot(self.robot)
        object.__setattr__(self, "at", _time(self.at, "at"))
        if self.restart is not None:
            object.__setattr__(self, "restart", _span_s(self.restart, "restart", "the time the robot is dead; "
                                                        "leave it out and the robot stays dead"))

    @property
    def end(self) -> float:
        return math.inf if self.restart is None else self.at + self.restart


@dataclass(frozen=True)
class Hang:
    """SIGSTOP robot's process at `at` s, SIGCONT `duration` s later."""

    robot: int
    at: float
    duration: float

    def __post_init__(self) -> None:
        _robot(self.robot)
        object.__setattr__(self, "at", _time(self.at, "at"))
        object.__setattr__(self, "duration", _span_s(self.duration, "duration", "the time the robot is stopped"))

    @property
    def end(self) -> float:
        return self.at + self.duration


def _span_s(value: Any, field: str, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise FaultError(field, f"must be a finite number of seconds, got {value!r}")
    if not value > 0:
        raise FaultError(field, f"must be > 0 s ({what}), got {value:g}")
    return float(value)


def _robot(robot: Any) -> None:
    if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)) or robot < 0:
        raise FaultError("robot", f"must be a robot id (an integer >= 0), got {robot!r}")


@dataclass(frozen=True)
class Faults:
    """Every fault of a run. Rule order is part of the model: rule r draws from its own streams."""

    seed: int = 0
    drops: tuple[DropRule, ...] = ()
    delays: tuple[DelayRule, ...] = ()
    partitions: tuple[Partition, ...] = ()
    kills: tuple[Kill, ...] = ()
    hangs: tuple[Hang, ...] = ()

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or not 0 <= self.seed < SEED_LIMIT:
            raise FaultError("seed", f"must be an integer in 0..2^63 - 1, got {self.seed!r}")
        object.__setattr__(self, "seed", int(self.seed))
        for name, most in (("drops", MAX_RULES), ("delays", MAX_RULES), ("partitions", MAX_PARTITIONS)):
            object.__setattr__(self, name, tuple(getattr(self, name)))
            if len(getattr(self, name)) > most:
                raise FaultError(name[:-1], f"lists {len(getattr(self, name))} rules; at most {most}")
        object.__setattr__(self, "kills", tuple(self.kills))
        object.__setattr__(self, "hangs", tuple(self.hangs))
        if len(self.kills) + len(self.hangs) > MAX_PROCESS_FAULTS:
            raise FaultError("kill", f"{len(self.kills) + len(self.hangs)} kills and hangs; at most {MAX_PROCESS_FAULTS}")
        _check_partitions(self.partitions)
        _check_process_faults(self.kills, self.hangs)

    @classmethod
    def empty(cls, seed: int = 0) -> Faults:
        return cls(seed=seed)

    def __bool__(self) -> bool:
        return bool(self.drops or self.delays or self.partitions or self.kills or self.hangs)


def _check_partitions(partitions: tuple[Partition, ...]) -> None:
    """Two partitions may not hold at once (the group of a robot would be ambiguous)."""
    # an empty window (end == start) holds no time: it overlaps nothing
    order = sorted((w for w in range(len(partitions)) if partitions[w].end > partitions[w].start),
                   key=lambda w: (partitions[w].start, w))
    for a, b in pairwise(order):
        pa, pb = partitions[a], partitions[b]
        if pb.start < pa.end:
            raise FaultError(f"partition[{b}].start", f"the window [{pb.start:g}, {pb.end:g}) s overlaps faults.partition[{a}]'s "
                             f"[{pa.start:g}, {pa.end:g}) s: one partition at a time (list all the groups in one)")


def _describe(kind: str, f: Kill | Hang) -> str:
    if kind == "kill":
        restart = cast(Kill, f).restart
        return (f"a kill at {f.at:g} s" + ("" if restart is None else f" with a restart at {f.end:g} s"))
    return f"a hang from {f.at:g} s to {f.end:g} s"


def _check_process_faults(kills: tuple[Kill, ...], hangs: tuple[Hang, ...]) -> None:
    """One process fault of a robot at a time: a hang of a dead robot, a second kill before the restart,
    anything after a kill without restart are refused; the later one is named."""
    by_robot: dict[int, list[tuple[float, int, str, int, Kill | Hang]]] = {}
    sources: tuple[tuple[str, tuple[Kill | Hang, ...]], ...] = (("kill", kills), ("hang", hangs))
    for kind, faults in sources:
        for k, f in enumerate(faults):
            by_robot.setdefault(f.robot, []).append((f.at, 0 if kind == "kill" else 1, kind, k, f))
    for robot in sorted(by_robot):
        items = sorted(by_robot[robot], key=lambda x: x[:4])
        for (_, _, ka, ia, fa), (_, _, kb, ib, fb) in pairwise(items):
            if fb.at < fa.end:
                state = "dead" if ka == "kill" else "stopped"
                until = "for good" if fa.end == math.inf else f"until {fa.end:g} s"
                raise FaultError(f"{kb}[{ib}].at", f"robot {robot} is {state} {until} ({_describe(ka, fa)}, "
                                 f"faults.{ka}[{ia}]): {_describe(kb, fb)} overlaps it (one process fault of a robot at a time)")


# --------------------------------------------------------------------------- reading


class _Reader(Reader):
    """The TOML reader, where a number of 1e308 or more in size is not finite (a time or a probability so large
    overflows what the schedule computes from it)."""

    def number(self, value: Any, key: str, **kw: Any) -> float:
        if not isinstance(value, bool) and isinstance(value, (int, float)) and not abs(value) < 1e308:
            raise self.fail(key, f"must be finite, got {value}")
        return super().number(value, key, **kw)


_RULE_KEYS = ("from", "to", "start", "end")


def _build(rd: _Reader, key: str, make: Callable[..., _T], **kw: Any) -> _T:
    """make(**kw) builds a rule (or the Faults); its FaultError becomes a ScenarioError at key.field."""
    try:
        return make(**kw)
    except FaultError as e:
        raise rd.fail(f"{key}.{e.field}", e.reason) from None


def _span(rd: _Reader, rule: dict[str, Any], key: str, duration: float) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if "start" in rule:
        out["start"] = rd.time(rule["start"], f"{key}.start")
    if "end" in rule:
        out["end"] = rd.number(rule["end"], f"{key}.end")
    return out


def _selection(rd: _Reader, rule: dict[str, Any], key: str, robots: int, duration: float) -> dict[str, Any]:
    out = _span(rd, rule, key, duration)
    if "from" in rule:
        out["senders"] = rd.robots(rule["from"], f"{key}.from", robots)
    if "to" in rule:
        out["receivers"] = rd.robots(rule["to"], f"{key}.to", robots)
    return out


def _drop(rd: _Reader, rule: Any, key: str, robots: int, duration: float) -> DropRule:
    rd.table(rule, key, ("class", "p", "burst", *_RULE_KEYS), ("class", "p"))
    return _build(rd, key, DropRule, cls=rule["class"], p=rd.number(rule["p"], f"{key}.p"),
                  burst=rd.number(rule.get("burst", 1.0), f"{key}.burst"),
                  **_selection(rd, rule, key, robots, duration))


def _delay(rd: _Reader, rule: Any, key: str, robots: int, duration: float) -> DelayRule:
    rd.table(rule, key, ("class", "ticks", "jitter", *_RULE_KEYS), ("class", "ticks"))
    return _build(rd, key, DelayRule, cls=rule["class"], ticks=rd.integer(rule["ticks"], f"{key}.ticks"),
                  jitter=rd.integer(rule.get("jitter", 0), f"{key}.jitter"),
                  **_selection(rd, rule, key, robots, duration))


def _partition(rd: _Reader, rule: Any, key: str, robots: int, duration: float) -> Partition:
    rd.table(rule, key, ("groups", "start", "end"), ("groups",))
    groups = rule["groups"]
    if not isinstance(groups, list) or not groups:
        got = "an empty list" if groups == [] else kind(groups)
        raise rd.fail(f"{key}.groups", f"must be a non-empty list of lists of robot ids, got {got}")
    groups = tuple(rd.robots(g, f"{key}.groups[{k}]", robots) for k, g in enumerate(groups))
    return _build(rd, key, Partition, groups=groups, **_span(rd, rule, key, duration))


def _kill(rd: _Reader, rule: Any, key: str, robots: int, duration: float) -> Kill:
    rd.table(rule, key, ("robot", "at", "restart"), ("robot", "at"))
    restart = rd.number(rule["restart"], f"{key}.restart") if "restart" in rule else None
    return _build(rd, key, Kill, robot=rd.robot(rule["robot"], f"{key}.robot", robots),
                  at=rd.time(rule["at"], f"{key}.at"), restart=restart)


def _hang(rd: _Reader, rule: Any, key: str, robots: int, duration: float) -> Hang:
    rd.table(rule, key, ("robot", "at", "duration"), ("robot", "at", "duration"))
    return _build(rd, key, Hang, robot=rd.robot(rule["robot"], f"{key}.robot", robots),
                  at=rd.time(rule["at"], f"{key}.at"),
                  duration=rd.number(rule["duration"], f"{key}.duration"))


def parse_faults(table: Any, where: str, robots: int, duration: float, default_seed: int) -> Faults:
    """Check the value of a [faults] table (as tomllib gives it) and return its Faults.

    robots: the scenario's robot count (ids 0..robots-1); duration [s]: the run's (a fault at or after
    it never happens and is refused); default_seed: the run's seed (taken modulo 2^63) when the table
    has no seed. Raises ScenarioError(where, "faults.KEY", reason)."""
    rd = _Reader(where)
    doc = rd.table(table, "faults", ("seed", "drop", "delay", "partition", "kill", "hang"))
    seed = rd.integer(doc["seed"], "faults.seed") if "seed" in doc else default_seed % SEED_LIMIT
    if seed >= SEED_LIMIT:
        raise rd.fail("faults.seed", f"must be below 2^63, got {seed}")
    rules = {}
    for name, most, read in (("drop", MAX_RULES, _drop), ("delay", MAX_RULES, _delay),
                             ("partition", MAX_PARTITIONS, _partition), ("kill", MAX_PROCESS_FAULTS, _kill),
                             ("hang", MAX_PROCESS_FAULTS, _hang)):
        items = rd.tables(doc.get(name, []), f"faults.{name}", most)
        rules[name] = tuple(read(rd, rule, f"faults.{name}[{i}]", robots, duration) for i, rule in enumerate(items))
    return _build(rd, "faults", Faults, seed=seed, drops=rules["drop"], delays=rules["delay"],
                  partitions=rules["partition"], kills=rules["kill"], hangs=rules["hang"])


def load_faults_file(path: str, robots: int, duration: float, default_seed: int) -> Faults:
    """The Faults of a --faults FILE: a TOML file holding only a [faults] table."""
    doc = read_toml(path, "faults file (TOML)")
    for k in doc:
        if k != "faults":
            raise ScenarioError(path, k, "a --faults file holds only a [faults] table")
    if "faults" not in doc:
        raise ScenarioError(path, "faults", "missing: a --faults file holds a [faults] table")
    return parse_faults(doc["faults"], path, robots, duration, default_seed)


# --------------------------------------------------------------------------- shorthands


def drop_shorthand(p: float) -> DropRule:
    """--drop P: one drop rule of class "all", every link, the whole run, independent losses."""
    if isinstance(p, bool) or not isinstance(p, (int, float)) or not 0.0 <= p <= 1.0:
        raise ScenarioError("command line", "--drop", f"must be a probability, 0 <= p <= 1, got {p!r}")
    return DropRule("all", float(p))


def kill_shorthand(text: str, robots: int, duration: float) -> tuple[Kill, ...]:
    """--kill ID@T[,ID@T...]: one kill (no restart) per item, robot ID at T simulated seconds."""
    items = [s.strip() for s in text.split(",")]
    if not text.strip():
        raise ScenarioError("command line", f"--kill {text!r}", "give ID@T[,ID@T...] (robot ID killed at T s)")
    out = []
    for item in items:
        key = f"--kill {item!r}"
        robot, at, rest = item.partition("@")
        if not at or not rest:
            raise ScenarioError("command line", key, "give ID@T (robot ID killed at T s), e.g. 2@5.5")
        try:
            i = int(robot.strip())
        except ValueError:
            raise ScenarioError("command line", key, f"the robot {robot.strip()!r} is not an integer id") from None
        try:
            t = float(rest.strip())
        except ValueError:
            raise ScenarioError("command line", key, f"the time {rest.strip()!r} is not a number of seconds") from None
        if not 0 <= i < robots:
            raise ScenarioError("command line", key, f"robot {i} is not in the scenario (it has {robots} robots: "
                                f"0..{robots - 1})")
        if not math.isfinite(t) or t < 0:
            raise ScenarioError("command line", key, f"the time must be a finite number >= 0 s, got {rest.strip()}")
        if t >= duration:
            raise ScenarioError("command line", key, f"{t:g} s is not before the end of the run (duration = "
                                f"{duration:g} s): the kill would never happen")
        out.append(Kill(i, t))
    return tuple(out)


def merged(faults: Faults, drops: Iterable[DropRule] = (), kills: Iterable[Kill] = ()) -> Faults:
    """faults plus shorthand rules (after the file's: rule indices of the file stay what they were)."""
    drops, kills = tuple(drops), tuple(kills)
    try:
        return Faults(faults.seed, faults.drops + drops, faults.delays, faults.partitions, faults.kills + kills,
                      faults.hangs)
    except FaultError as e:
        flag = "--drop" if e.field.startswith("drop") else "--kill"
        raise ScenarioError("command line", flag, f"with the faults given: {e.reason}") from None


def advisories(faults: Faults, duration: float, robots: int | None = None) -> list[str]:
    """Valid but odd choices, to warn about: rules that never act (no link, an empty window, a time after the
    run's last step, one group of every robot), a burst raised to what p needs, restarts and resumes after
    it. duration [s]: the time of the run's last step (steps x dt: a fault at it still acts there)."""
    out = []
    end = duration + fg.TIME_EPS
    d: DropRule | DelayRule
    for i, d in enumerate(faults.drops):
        if d.p == 0.0:
            out.append(f"faults.drop[{i}] has p = 0: it never loses a message")
        if d.burst_given is not None:
            out.append(f"faults.drop[{i}] has burst = {d.burst_given:g}, shorter than p = {d.p:g} allows (bursts "
                       f"of mean length b lose at most b / (b + 1) of the messages): its bursts are p / (1 - p) = "
                       f"{d.burst:.4g} messages long on average, so that it loses p of them")
    for i, d in enumerate(faults.delays):
        if d.ticks == 0 and d.jitter == 0:
            out.append(f"faults.delay[{i}] has ticks = 0 and jitter = 0: it never delays a message")
    windows: tuple[tuple[str, tuple[DropRule | DelayRule | Partition, ...]], ...] = (
        ("drop", faults.drops), ("delay", faults.delays), ("partition", faults.partitions))
    for name, rules in windows:
        for i, r in enumerate(rules):
            links = cast("DropRule | DelayRule", r)  # read only when name != "partition"
            why = None if name == "partition" else _matches_nothing(links.cls, links.senders, links.receivers)
            if why is not None:
                out.append(f"faults.{name}[{i}] matches no message: {why}")
            elif r.start > end:
                out.append(f"faults.{name}[{i}] starts at {r.start:g} s, after the run's last step "
                           f"({duration:g} s): it never acts")
            elif r.end <= r.start:
                out.append(f"faults.{name}[{i}] has an empty window (start = end = {r.start:g} s): it never acts")
    for i, pt in enumerate(faults.partitions):
        if robots is not None and len(pt.groups) + (sum(len(g) for g in pt.groups) < robots) < 2:
            out.append(f"faults.partition[{i}] puts all {robots} robots in one group (the robots in no group form one "
                       "more group): it separates nothing")
    process: tuple[tuple[str, tuple[Kill | Hang, ...]], ...] = (("kill", faults.kills), ("hang", faults.hangs))
    for name, events in process:
        for i, e in enumerate(events):
            if e.at > end:
                out.append(f"faults.{name}[{i}] is at {e.at:g} s, after the run's last step ({duration:g} s): it "
                           "never happens")
    for i, k in enumerate(faults.kills):
        if k.restart is not None and k.at <= end and k.end >= duration:
            out.append(f"faults.kill[{i}] restarts robot {k.robot} at {k.end:g} s, not before the run's last step "
                       f"({duration:g} s): it stays dead")
    for i, h in enumerate(faults.hangs):
        if h.at <= end and h.end >= duration:
            out.append(f"faults.hang[{i}] resumes robot {h.robot} at {h.end:g} s, not before the run's last step "
                       f"({duration:g} s): it stays stopped")
    return out


def partitions_begun(faults: Faults, t_end: float) -> int:
    """The metrics' faults.partitions: partition windows that began by t_end [s] (the run's last step) and
    hold some time; one that starts after the end, or an empty one, never happened."""
    return sum(1 for p in faults.partitions if p.start - 1e-9 <= t_end and p.end > p.start)


# --------------------------------------------------------------------------- canonical text


def to_toml(faults: Faults) -> str:
    """The canonical [faults] text: every key written (an open window's end left out), rules in order,
    numbers as repr(float); it loads back to an equal Faults. "" when there is no rule, so a run
    without faults keeps the scenario text (and digest) it had."""
    if not faults:
        return ""

    def num(x: float) -> str:
        return repr(float(x))

    def ids(v: Iterable[int]) -> str:
        return "[" + ", ".join(str(i) for i in v) + "]"

    def sel(rule: DropRule | DelayRule) -> list[str]:
        out = []
        if rule.senders is not None:
            out.append(f"from = {ids(rule.senders)}")
        if rule.receivers is not None:
            out.append(f"to = {ids(rule.receivers)}")
        out.append(f"start = {num(rule.start)}")
        if rule.end != math.inf:
            out.append(f"end = {num(rule.end)}")
        return out

    lines = ["[faults]", f"seed = {faults.seed}"]
    d: DropRule | DelayRule
    for d in faults.drops:
        lines += ["", "[[faults.drop]]", f'class = "{d.cls}"', f"p = {num(d.p)}", f"burst = {num(d.burst)}", *sel(d)]
    for d in faults.delays:
        lines += ["", "[[faults.delay]]", f'class = "{d.cls}"', f"ticks = {d.ticks}", f"jitter = {d.jitter}", *sel(d)]
    for w in faults.partitions:
        lines += ["", "[[faults.partition]]", "groups = [" + ", ".join(ids(g) for g in w.groups) + "]",
                  f"start = {num(w.start)}"] + ([f"end = {num(w.end)}"] if w.end != math.inf else [])
    for k in faults.kills:
        lines += ["", "[[faults.kill]]", f"robot = {k.robot}", f"at = {num(k.at)}"] + \
            ([f"restart = {num(k.restart)}"] if k.restart is not None else [])
    for h in faults.hangs:
        lines += ["", "[[faults.hang]]", f"robot = {h.robot}", f"at = {num(h.at)}", f"duration = {num(h.duration)}"]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- schedule queries


def _in(t: float, start: float, end: float) -> bool:
    return start - fg.TIME_EPS <= t < end - fg.TIME_EPS


def partition_group(faults: Faults, robot: int, t: float) -> int:
    """The group of robot (or WORLD / LEADER) at time t [s]: 0 for the first group (the world's and
    the leader's), and 0 for everyone outside every partition's window."""
    if robot < 0:
        return 0
    for w in faults.partitions:
        if _in(t, w.start, w.end):
            return w.group(robot)
    return 0


def cut(faults: Faults, sender: int, receiver: int, t: float) -> bool:
    """Whether a partition separates sender from receiver at t [s]: a state link (j, i) or a reference
    link (LEADER, i). A pose or a command (a link with the world) is the robot's own body: never cut."""
    if sender == WORLD or receiver == WORLD:
        return False
    return partition_group(faults, sender, t) != partition_group(faults, receiver, t)


def process_state(faults: Faults, robot: int, t: float) -> str:
    """"alive", "dead" (killed, before its restart) or "hung" (stopped, before it resumes) at t [s]."""
    for k in faults.kills:
        if k.robot == robot and _in(t, k.at, k.end):
            return "dead"
    for h in faults.hangs:
        if h.robot == robot and _in(t, h.at, h.end):
            return "hung"
    return "alive"


def events(faults: Faults) -> list[tuple[float, int, str]]:
    """Every process event (t [s], robot, kind), kind in KINDS, sorted by time, then robot, then ends
    before starts (a restart at t comes before a hang at t)."""
    out = []
    for k in faults.kills:
        out.append((k.at, k.robot, "kill"))
        if k.restart is not None:
            out.append((k.end, k.robot, "restart"))
    for h in faults.hangs:
        out += [(h.at, h.robot, "hang"), (h.end, h.robot, "resume")]
    return sorted(out, key=lambda e: (e[0], e[1], _KIND_ORDER[e[2]]))


def timeline(faults: Faults, robots: int) -> list[tuple[float, str, tuple[int, ...], str]]:
    """What a viewer is told, in time order: (t [s], event, robots, detail) for every process event
    (kill, restart, hang, resume: the robot named) and every partition's start and end (partition,
    partition_end: the robots cut off from the world's group, which is the first)."""
    out: list[tuple[float, str, tuple[int, ...], str]] = []
    for t, robot, kind in events(faults):
        detail = {"kill": "its process is killed", "restart": "a new process takes it over",
                  "hang": "its process is stopped", "resume": "its process goes on"}[kind]
        for k in faults.kills:
            if kind == "kill" and k.robot == robot and k.at == t:
                detail += f" (restarted after {k.restart:g} s)" if k.restart is not None else " (for good)"
        out.append((t, kind, (robot,), detail))
    for p in faults.partitions:
        grouped = {i for g in p.groups for i in g}
        rest = tuple(i for i in range(robots) if i not in grouped)
        groups = [list(g) for g in p.groups] + ([list(rest)] if rest else [])
        cut = tuple(sorted(i for g in groups[1:] for i in g))
        text = " | ".join(", ".join(map(str, g)) for g in groups)
        out.append((p.start, "partition", cut, f"groups {text} (the world and the leader with the first)"))
        if math.isfinite(p.end):
            out.append((p.end, "partition_end", cut, f"groups {text} joined again"))
    return sorted(out, key=lambda e: (e[0], e[1] != "partition_end"))

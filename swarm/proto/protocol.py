"""Messages of docs/protocol.md and their one versioned msgpack codec.

    payload = encode(Cmd(t=1.0, seq=50, v=0.4, w=-0.1))
    msg = decode(payload, kind="cmd", key_id=7)      # raises ProtocolError if anything is off

Every payload is a msgpack map {"v": 1, "kind": ..., fields}. decode() validates at the
boundary: size, msgpack, version, kind, the exact set of fields, types (bool is not a
number), finite numbers, ranges (ids and seq >= 0, 0 < r < R, speeds, coordinates and times
within physical bounds), and the id in the key equal to the id in the payload; with `limits`
(a Limits from the scenario) also the scenario's ids, radii, speed bounds and arena. Anything
wrong raises ProtocolError with a reason, and nothing else: a crafted payload of any shape
cannot make decode() raise another exception. A process drops and counts such a message
(swarm.proto.protocol.BadMessages) and goes on. The bounds and the windows that receivers keep
per sender (swarm.proto.window) are in docs/protocol.md.
"""

from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import MISSING, dataclass, fields
from typing import TYPE_CHECKING, overload

import msgpack
from swarm.core.errors import SwarmError

if TYPE_CHECKING:
    from collections.abc import Callable, ValuesView
    from typing import Any, Literal, Protocol, TypeAlias, TypeVar

try:  # the compiled wire codec of the kinds of every period (setup.py builds it where a C compiler is found)
    from swarm.proto import _wire as _wire  # re-exported: other modules read protocol._wire
except ImportError:
    _wire = None

if os.environ.get("SWARM_PURE_PYTHON"):  # the generated Python codec alone (tests compare the two)
    _wire = None

VERSION = 1
MAX_PAYLOAD = 64 << 10  # bytes: any message but the large kinds (a state is ~100 bytes); larger is refused unread
MAX_LARGE_PAYLOAD = 16 << 20  # bytes: snapshot, obstacles, run (a snapshot of 100 000 robots is ~10 MB)
LARGE_KINDS = ("snapshot", "obstacles", "run", "bodies")
MAX_ROBOTS = 100_000
MAX_SPEED = 100.0  # m/s: |vel| of any command, reference or snapshot
MAX_TURN = 100.0  # rad/s: |w|
MAX_COORD = 1e6  # m: |x|, |y| of any position (poses, states, references, obstacles, offsets)
MAX_ANGLE = 1e6  # rad: |theta| (the leader's heading is not wrapped)
MAX_TIME = 1e9  # s: |t|
MAX_TEXT = 256  # characters of a short string field (run id, digest)


class ProtocolError(SwarmError, ValueError):
    """A message that must not reach the law: the reason says what was wrong."""


@dataclass(frozen=True, slots=True)
class Ref:
    """The leader's live reference (leader -> agents)."""

    t: float
    seq: int
    x: float
    y: float
    theta: float
    v: float
    w: float


@dataclass(frozen=True, slots=True)
class Pose:
    """A robot's pose (world or localization -> agent)."""

    t: float
    seq: int
    x: float
    y: float
    theta: float
    # real time, optional (None: absent): the t of the newest command the drive executes now (the command's own t,
    # the time of the pose it answered; < 0: none yet): a robot sees how long its commands take to act
    cmd: float | None = None


@dataclass(frozen=True, slots=True)
class Cmd:
    """A robot's command (agent -> world or drive)."""

    t: float
    seq: int
    v: float
    w: float
    # real time: the swarm-clock time [s] until which a drive may execute this command; then it brakes along
    # its ramp (docs/runtime.md, "The safety invariant"). Optional on the wire: None (absent) means the
    # drive's own rule (the period the command was meant for and one more, then the ramp).
    until: float | None = None


@dataclass(frozen=True, slots=True)
class State:
    """A robot's state on its cell key (agent -> agents nearby)."""

    id: int
    t: float
    seq: int
    x: float
    y: float
    theta: float
    r: float
    R: float
    frozen: bool
    # real time, optional on the wire (None: absent): what bounds this robot's motion from (x, y). stop [m]: the
    # most it moves from there if it sends no further command (its commands' validity and the brake ramp);
    # still [s]: a promise that it sends no command that moves it before that time (standing robots). A
    # receiver that has neither assumes the speed bound over the state's age (docs/runtime.md).
    stop: float | None = None
    still: float | None = None


@dataclass(frozen=True, slots=True)
class Status:
    """A robot's status (agent -> viewers, recorder)."""

    t: float
    ex: float
    ey: float
    etheta: float
    frozen: bool
    neighbours: int
    stale: int
    bad: int
    # real time, optional: the share of this robot's commands so far that its safety rule held back (slowed or
    # stopped below what its law asked), in [0, 1]
    held: float | None = None


@dataclass(frozen=True)
class Obstacle:
    x: float
    y: float
    r: float
    R: float


@dataclass(frozen=True)
class Obstacles:
    """The world's static obstacles (reply of the obstacles queryable)."""

    obstacles: tuple[Obstacle, ...]


@dataclass(frozen=True)
class RobotSnap:
    id: int
    x: float
    y: float
    theta: float
    v: float
    w: float
    stopped: bool
    alive: bool


@dataclass(frozen=True)
class Snapshot:
    """Every robot at one tick (world -> viewers, recorder)."""

    t: float
    seq: int
    robots: tuple[RobotSnap, ...]


@dataclass(frozen=True)
class Clock:
    """The world's clock (world -> leader, agents; an extension key). Lock-step: tick seq at time t
    (clock 0 also says every robot's first state has been delivered). Real time: t = (unix time -
    epoch) * speed, so every process can run the same simulated clock from its own wall clock."""

    t: float
    seq: int
    epoch: float  # unix time [s] of t = 0 in real time; 0.0 in lock-step
    speed: float  # simulated seconds per wall second (> 0)


@dataclass(frozen=True)
class Config:
    """One robot's slice of the scenario (reply of the world's config queryable): its id, start
    pose, formation offset, radii, gains and timing; never another robot's state."""

    id: int
    x: float  # start pose
    y: float
    theta: float
    dx: float  # formation offset d_i
    dy: float
    r: float
    R: float
    k1: float
    k2: float
    k3: float
    tu: float
    vt: float
    threshold: int  # swarm.core.law.THRESHOLD_*
    governor: bool
    dt: float  # control period [s]
    sense: float  # cell side = sensing range [m]
    reach: float  # the largest R of any body [m]: bodies closer than this act on the command (R <= reach < sense)
    lockstep: bool
    robots: int = 1  # robots in the scenario: ids are 0 .. robots - 1
    v_max: float = 0.0  # the speed bound control.v_max [m/s]; 0: none
    w_max: float = 0.0  # control.w_max [rad/s]; 0: none
    run: str = ""  # the run this configuration belongs to (Run.run)
    digest: str = ""  # the digest of the run's resolved scenario (Run.digest)
    arena: bool = False  # arena.bounds set: a drive stops its robot outside [xmin, xmax] x [ymin, ymax]
    xmin: float = 0.0
    xmax: float = 0.0
    ymin: float = 0.0
    ymax: float = 0.0
    v_bound: float = 1.0  # real time: the speed bound [m/s] every robot keeps to and assumes of every other
    # a law of the user's own (docs/control.md), all four or none (None: the paper's law)
    law: str | None = None  # where it is: "/abs/path/file.py:NAME" or "package.module:NAME"
    law_sha256: str | None = None  # of its file: the robot checks its own copy against it
    law_params: tuple[float, ...] | None = None  # [control] params
    law_memory: int | None = None  # [control] memory: floats of memory per robot


@dataclass(frozen=True)
class Body:
    id: int
    x: float
    y: float
    r: float
    R: float


@dataclass(frozen=True)
class Bodies:
    """Lock-step under faults (world -> every agent, each tick before its poses): the static bodies at
    tick seq, robots that are dead or stopped by the watchdog, where they stand (every agent takes them
    as bodies, neighbours or not); and the robots returning at seq (restarted or resumed: their first
    pose, which is their state of that tick, so nobody waits for it)."""

    t: float
    seq: int
    bodies: tuple[Body, ...]
    returning: tuple[Body, ...] = ()


@dataclass(frozen=True)
class FaultStats:
    """A robot's fault counters (agent -> world, lock-step under faults, each tick before its command):
    what its fault layer lost or delayed so far of its neighbours' states, its poses and its references,
    and the oldest neighbour state its law used [s]. A restarted robot counts from 0 again."""

    t: float
    seq: int
    dropped_state: int
    dropped_pose: int
    dropped_ref: int
    delayed_state: int
    delayed_pose: int
    delayed_ref: int
    max_age: float
    frozen: bool  # its law froze it at seq (the metrics' freezes under faults are the laws' own)


@dataclass(frozen=True)
class Estop:
    """The emergency stop (operator -> every drive): engaged, every robot holds zero velocity until a
    release (engaged false). t is the operator's unix time [s], seq its counter (unix time in ms)."""

    t: float
    seq: int
    engaged: bool
    reason: str


@dataclass(frozen=True)
class Proc:
    """A process of the swarm says who it is (its proc queryable's reply: `swarm ps`): its role and id (as in its
    liveliness token), the machine's host name, its pid, when it started (unix time [s]), the run it is in ("" for
    none yet) and the swarm version it runs."""

    role: str
    id: int
    host: str
    pid: int
    started: float
    run: str
    version: str


@dataclass(frozen=True)
class Run:
    """A run's identity (world -> everyone, and the world's run queryable): a new id at every run's
    start; digest = sha256 of the resolved scenario (faults included) as canonical TOML. The
    queryable's reply also carries that TOML in `scenario` (so a robot can name the first
    difference from its own); the publication leaves it empty."""

    run: str
    digest: str
    robots: int
    lockstep: bool
    scenario: str


@dataclass(frozen=True)
class Progress:
    """A run's progress (world -> launcher, viewers; an extension key). min_distance < 0: none yet."""

    t: float
    seq: int
    duration: float
    robots: int
    alive: int
    converged: int
    frozen: int
    min_distance: float
    misses: int
    bad: int
    collisions: int = 0
    overruns: int = 0
    min_obstacle: float = -1.0  # m; < 0: none yet
    position_error: float = -1.0  # m, the largest over live robots at t; < 0: not known
    orientation_error: float = -1.0  # rad
    converged_at: float = -1.0  # s; < 0: not converged (so far)
    last_freeze: float = -1.0  # s; < 0: no freeze yet
    dropped: int = 0  # messages dropped by scheduled faults
    hung: int = 0  # robots whose process is hung now (by the fault schedule)
    held: float = -1.0  # real time: the share of commands the robots' safety rule held back so far; < 0: none known
    stranded: int = 0  # live robots stranded far from their slots now (docs/metrics.md)


EVENTS = ("kill", "restart", "hang", "resume", "partition", "partition_end", "signal", "estop", "estop_release")


@dataclass(frozen=True)
class Event:
    """A fault or supervision event (world, swarm up -> viewers, recorders; world/events): a scheduled
    process event of the robots named (kill, restart, hang, resume), a partition that begins or ends
    (robots: every robot cut off from the world's group), or a signal the supervisor sent (signal)."""

    t: float  # simulated time [s]
    seq: int  # the tick (lock-step) or period (real time)
    event: str  # one of EVENTS
    robots: tuple[int, ...]
    detail: str


@dataclass(frozen=True)
class Claim:
    """The world's answer to a robot started with --id auto (reply of world/claim/<claim key>): the id it
    may take (granted), or why not. The id is provisional until that robot's liveliness token appears
    (world.claims)."""

    id: int
    claim: str  # the claim key asked for (a hostname, say)
    granted: bool
    robots: int  # robots in the run: ids 0 .. robots - 1
    reason: str  # why not granted ("" when granted)


if TYPE_CHECKING:
    Message: TypeAlias = (Ref | Pose | Cmd | State | Status | Obstacles | Snapshot | Clock | Config | Progress | Run
                          | Estop | Bodies | Claim | FaultStats | Event | Proc)
    HotMessage: TypeAlias = State | Pose | Ref | Cmd  # the kinds of every control period (decoder())
    _M_co = TypeVar("_M_co", covariant=True)

    class Decoder(Protocol[_M_co]):
        """What decoder() returns: f(payload, key_id=None) -> the message (ProtocolError if anything is off)."""

        def __call__(self, payload: bytes, key_id: int | None = None, /) -> _M_co: ...


KINDS: dict[str, type[Message]] = {"ref": Ref, "pose": Pose, "cmd": Cmd, "state": State, "status": Status,
                                   "obstacles": Obstacles, "snapshot": Snapshot, "clock": Clock, "config": Config,
                                   "progress": Progress, "run": Run, "estop": Estop, "bodies": Bodies, "claim": Claim,
                                   "faultstats": FaultStats, "event": Event, "proc": Proc}
_KIND_OF = {cls: kind for kind, cls in KINDS.items()}


def kind_of(msg: Message) -> str:
    """The kind of a message ("state", "pose", ...), as it goes on the wire."""
    return _KIND_OF[type(msg)]


def _fast_init(cls: type[Any]) -> None:
    """Give a frozen dataclass an __init__ that fills its __dict__ directly (or, with __slots__, each slot
    through its descriptor): the same signature and defaults, the same object (fields, eq, hash, repr, frozen
    after it), built in a third of the time (a frozen dataclass's own __init__ calls object.__setattr__ once
    per field: about 2 us for a state, and a robot builds several messages every control period)."""
    ns: dict[str, Any] = {}
    params, stores = [], []
    slotted = "__slots__" in cls.__dict__
    for f in fields(cls):
        if f.default_factory is not MISSING:
            raise TypeError(f"{cls.__name__}.{f.name}: a default factory is not supported here")
        if f.default is MISSING:
            params.append(f.name)
        else:
            ns[f"_default_{f.name}"] = f.default
            params.append(f"{f.name}=_default_{f.name}")
        if slotted:
            ns[f"_set_{f.name}"] = cls.__dict__[f.name].__set__
            stores.append(f"    _set_{f.name}(self, {f.name})")
        else:
            stores.append(f"    d[{f.name!r}] = {f.name}")
    names = [f.name for f in fields(cls)]
    if slotted and _wire is not None:  # every slot in one compiled call (swarm/proto/_wire.c)
        ns["_fill"] = _wire.Filler(cls, tuple(names))
        stores = [f"    _fill(self, {', '.join(names)})"]
    head = "" if slotted else "    d = self.__dict__\n"
    src = f"def __init__(self, {', '.join(params)}):\n{head}" + "\n".join(stores)
    exec(compile(src, f"<protocol __init__ of {cls.__name__}>", "exec"), ns)
    ns["__init__"].__qualname__ = f"{cls.__name__}.__init__"
    cls.__init__ = ns["__init__"]


for _cls in (*KINDS.values(), Obstacle, RobotSnap, Body):
    _fast_init(_cls)


# --------------------------------------------------------------------------- encoding


def encode(msg: Any) -> bytes:
    """msgpack bytes of a message (no validation: messages are built by this process)."""
    cls = type(msg)
    fast = _FAST_ENCODE.get(cls)
    if fast is not None:
        return fast(msg)
    kind = _KIND_OF.get(cls)
    if kind is None:
        raise TypeError(f"not a protocol message: {cls.__name__}")
    if kind in _SPEC:  # a flat kind's first message: generate its encoder (kept for the next ones)
        fast = _FAST_ENCODE[cls] = _compile_encode(kind)
        return fast(msg)
    d: dict[str, Any] = {"v": VERSION, "kind": kind}
    if kind == "obstacles":
        d["obstacles"] = [{"x": o.x, "y": o.y, "r": o.r, "R": o.R} for o in msg.obstacles]
    elif kind == "event":
        d.update(t=msg.t, seq=msg.seq, event=msg.event, robots=list(msg.robots), detail=msg.detail)
    elif kind == "bodies":
        d.update(t=msg.t, seq=msg.seq, bodies=[{"id": b.id, "x": b.x, "y": b.y, "r": b.r, "R": b.R} for b in msg.bodies],
                 returning=[{"id": b.id, "x": b.x, "y": b.y, "r": b.r, "R": b.R} for b in msg.returning])
    elif kind == "snapshot":
        d.update(t=msg.t, seq=msg.seq,
                 robots=[{f: getattr(s, f) for f in _SNAP_FIELDS} for s in msg.robots])
    else:
        for name, wire in _WIRE_NAMES[kind]:
            d[wire] = getattr(msg, name)
    payload: bytes = msgpack.packb(d, use_bin_type=True)
    return payload


# --------------------------------------------------------------------------- decoding


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


_SPEC: dict[str, tuple[tuple[str, str], ...]] = {
    "ref": (("t", "n"), ("seq", "i"), ("x", "n"), ("y", "n"), ("theta", "n"), ("vel", "n"), ("w", "n")),
    "pose": (("t", "n"), ("seq", "i"), ("x", "n"), ("y", "n"), ("theta", "n"), ("cmd", "n")),
    "cmd": (("t", "n"), ("seq", "i"), ("vel", "n"), ("w", "n"), ("until", "n")),
    "state": (("id", "id"), ("t", "n"), ("seq", "i"), ("x", "n"), ("y", "n"), ("theta", "n"), ("r", "n"),
              ("R", "n"), ("frozen", "b"), ("stop", "n"), ("still", "n")),
    "status": (("t", "n"), ("ex", "n"), ("ey", "n"), ("etheta", "n"), ("frozen", "b"), ("neighbours", "i"),
               ("stale", "i"), ("bad", "i"), ("held", "n")),
    "clock": (("t", "n"), ("seq", "i"), ("epoch", "n"), ("speed", "n")),
    "config": (("id", "id"), ("x", "n"), ("y", "n"), ("theta", "n"), ("dx", "n"), ("dy", "n"), ("r", "n"),
               ("R", "n"), ("k1", "n"), ("k2", "n"), ("k3", "n"), ("tu", "n"), ("vt", "n"), ("threshold", "i"),
               ("governor", "b"), ("dt", "n"), ("sense", "n"), ("reach", "n"), ("lockstep", "b"), ("robots", "i"),
               ("v_max", "n"), ("w_max", "n"), ("run", "s"), ("digest", "s"), ("arena", "b"), ("xmin", "n"),
               ("xmax", "n"), ("ymin", "n"), ("ymax", "n"), ("v_bound", "n"), ("law", "s"),
               ("law_sha256", "s"), ("law_params", "f"), ("law_memory", "i")),
    "progress": (("t", "n"), ("seq", "i"), ("duration", "n"), ("robots", "i"), ("alive", "i"),
                 ("converged", "i"), ("frozen", "i"), ("min_distance", "n"), ("misses", "i"), ("bad", "i"),
                 ("collisions", "i"), ("overruns", "i"), ("min_obstacle", "n"), ("position_error", "n"),
                 ("orientation_error", "n"), ("converged_at", "n"), ("last_freeze", "n"), ("dropped", "i"),
                 ("hung", "i"), ("held", "n"), ("stranded", "i")),
    "run": (("run", "s"), ("digest", "s"), ("robots", "i"), ("lockstep", "b"), ("scenario", "S")),
    "estop": (("t", "n"), ("seq", "i"), ("engaged", "b"), ("reason", "s")),
    "faultstats": (("t", "n"), ("seq", "i"), ("dropped_state", "i"), ("dropped_pose", "i"), ("dropped_ref", "i"),
                   ("delayed_state", "i"), ("delayed_pose", "i"), ("delayed_ref", "i"), ("max_age", "n"),
                   ("frozen", "b")),
    "claim": (("id", "id"), ("claim", "s"), ("granted", "b"), ("robots", "i"), ("reason", "s")),
    "proc": (("role", "s"), ("id", "i"), ("host", "s"), ("pid", "i"), ("started", "n"), ("run", "s"), ("version", "s")),
}
# Fields a sender may leave out (the real-time safety fields: docs/protocol.md); absent, the message's field is
# None. Encoders leave out a None one; a message that has them all takes the fast paths (generated and compiled
# decoders, which know the full layout only), one without them the general path.
_OPTIONAL: dict[str, tuple[str, ...]] = {"pose": ("cmd",), "cmd": ("until",), "state": ("stop", "still"),
                                         "status": ("held",),
                                         "config": ("law", "law_sha256", "law_params", "law_memory")}
# The key-space contract names both the protocol version and the linear velocity of ref and cmd
# "v"; one map cannot hold both. "v" stays the version (a decoder needs it before the kind);
# on the wire the linear velocity is "vel" (docs/protocol.md). In Python it is still .v.
_WIRE = {"v": "vel"}
_FIELD = {"vel": "v"}
_WIRE_NAMES = {k: tuple((f.name, _WIRE.get(f.name, f.name)) for f in fields(cls)) for k, cls in KINDS.items()}
MAX_LAW_PARAMS = 64  # numbers in a config's law_params
MAX_LAW_MEMORY = 1024  # floats of a user law's memory per robot


def _floats(d: dict[str, Any], name: str) -> tuple[float, ...]:
    x = d[name]
    if not isinstance(x, list) or len(x) > MAX_LAW_PARAMS:
        raise ProtocolError(f"field {name!r} must be a list of at most {MAX_LAW_PARAMS} numbers")
    return tuple(_num({name: v}, name) for v in x)


_READ: dict[str, Callable[[dict[str, Any], str], Any]] = {
    "f": _floats, "n": _num, "i": _int, "b": _bool, "id": lambda d, n: _int(d, n, MAX_ROBOTS - 1), "s": _text,
    "S": lambda d, n: _text(d, n, MAX_LARGE_PAYLOAD)}


def _compile_fast(kind: str) -> Callable[[dict[str, Any]], Any]:
    """A decoder for the common case of a flat kind: exactly the fields of the spec, floats that are
    floats and finite, ints in range, bools. It returns the message, or None for anything else, and
    decode() then takes the general path, which accepts ints for numbers and names what is wrong.
    Generated once per kind (as dataclasses and namedtuple do): straight-line code is 3x faster than
    the general path, and a robot decodes ~10 messages per control period."""
    spec = _SPEC[kind]
    wire = {_FIELD.get(n, n): n for n, _ in spec}  # python name -> wire name
    var = {n: f"a{i}" for i, (n, _) in enumerate(spec)}
    floats = [var[n] for n, t in spec if t == "n"]
    body = ["def fast(d):",
            f"    if len(d) != {len(spec) + 2} or d.get('kind') != {kind!r} or d.get('v') != {VERSION} "
            "or type(d['v']) is not int:",
            "        return None",
            "    try:",
            *[f"        {var[n]} = d[{n!r}]" for n, _ in spec],
            "    except KeyError:",
            "        return None"]
    for n, t in spec:
        a = var[n]
        if t == "n":
            body.append(f"    if type({a}) is not float: return None")
        elif t == "b":
            body.append(f"    if type({a}) is not bool: return None")
        elif t in ("s", "S"):
            limit = MAX_TEXT if t == "s" else MAX_LARGE_PAYLOAD
            body.append(f"    if type({a}) is not str or len({a}) > {limit}: return None")
        else:
            limit = MAX_ROBOTS - 1 if t == "id" else 2**53
            body.append(f"    if type({a}) is not int or not 0 <= {a} <= {limit}: return None")
    if floats:  # finite iff their sum minus itself is 0 (inf and nan propagate; an overflow goes the long way)
        body += [f"    s = {' + '.join(floats)}", "    if s - s != 0.0: return None"]
    args = ", ".join(var[wire[f.name]] for f in fields(KINDS[kind]))
    body.append(f"    return cls({args})")
    ns: dict[str, Any] = {"cls": KINDS[kind]}
    exec(compile("\n".join(body), f"<protocol fast decoder for {kind}>", "exec"), ns)
    fast: Callable[[dict[str, Any]], Any] = ns["fast"]
    return fast


# Generated on first use of each kind (a process uses a few; compiling all at import cost ~15 ms of
# every process's start, 40 times over at `swarm up`).
_FAST: dict[str, Callable[[dict[str, Any]], Any]] = {}


def _compile_encode(kind: str) -> Callable[[Message], bytes]:
    """encode() for a flat kind as one dict display (the general loop costs 3x as much)."""
    items = ", ".join(f"{wire!r}: m.{name}" for name, wire in _WIRE_NAMES[kind])
    optional = _OPTIONAL.get(kind, ())
    src = f"def enc(m):\n    d = {{'v': {VERSION}, 'kind': {kind!r}, {items}}}\n"
    src += "".join(f"    if m.{_FIELD.get(n, n)} is None:\n        del d[{n!r}]\n" for n in optional)
    src += "    return packb(d, use_bin_type=True)"
    ns: dict[str, Any] = {"packb": msgpack.packb}
    exec(compile(src, f"<protocol fast encoder for {kind}>", "exec"), ns)
    enc: Callable[[Message], bytes] = ns["enc"]
    order = _wire_order(kind)
    if _wire is None or any(t not in ("n", "i", "id", "b") for _, t, _ in order):
        return enc
    compiled: Callable[[Message], bytes] = _wire.Encoder(kind, VERSION, order, enc, KINDS[kind])
    return compiled


def encoder(kind: str) -> Callable[..., bytes]:
    """f(*fields) -> bytes: encode(cls(*fields)) for a flat kind, its fields given in the dataclass's order,
    without building the message where the compiled codec is (a robot's own state and command, every period)."""
    if kind not in _SPEC:
        raise ValueError(f"{kind!r} is not a flat message kind")
    cls = KINDS[kind]
    fast = _FAST_ENCODE.get(cls)
    if fast is None:  # generated once, as encode() would
        fast = _FAST_ENCODE[cls] = _compile_encode(kind)
    if _wire is not None and isinstance(fast, _wire.Encoder):
        compiled: Callable[..., bytes] = fast
        return compiled
    return lambda *fields: fast(cls(*fields))


def _wire_order(kind: str) -> list[tuple[str, str, str]]:
    """A flat kind's fields as the compiled codec takes them: (wire name, _SPEC type, Python name), in the
    encoder's order (the dataclass's)."""
    types = dict(_SPEC[kind])
    return [(wire, types[wire], name) for name, wire in _WIRE_NAMES[kind]]


_FAST_ENCODE: dict[type[Message], Callable[[Message], bytes]] = {}
_unpackb = msgpack.unpackb


class _DuplicateKey(SwarmError):
    """Raised inside msgpack's unpacking by _unique; decode() turns it into a ProtocolError."""


def _unique(pairs: list[tuple[Any, Any]]) -> dict[Any, Any]:
    """A map's pairs as a dict, refusing a key that comes twice (msgpack would keep the last silently: one reader
    would see one value and another reader the other)."""
    d = dict(pairs)
    if len(d) != len(pairs):
        raise _DuplicateKey
    return d


def _entries(payload: bytes) -> int:
    """The entry count in the header of the msgpack map `payload` starts with (-1: not a map header): a dict
    decoded from it with fewer keys had a key twice."""
    b = payload[0] if payload else 0
    if 0x80 <= b <= 0x8F:
        return b & 0x0F
    if b == 0xDE:
        return int.from_bytes(payload[1:3], "big")
    if b == 0xDF:
        return int.from_bytes(payload[1:5], "big")
    return -1


@overload
def decode(payload: bytes, kind: Literal["ref"], key_id: int | None = None, limits: Limits | None = None) -> Ref: ...
@overload
def decode(payload: bytes, kind: Literal["pose"], key_id: int | None = None, limits: Limits | None = None) -> Pose: ...
@overload
def decode(payload: bytes, kind: Literal["cmd"], key_id: int | None = None, limits: Limits | None = None) -> Cmd: ...
@overload
def decode(payload: bytes, kind: Literal["state"], key_id: int | None = None,
           limits: Limits | None = None) -> State: ...
@overload
def decode(payload: bytes, kind: Literal["status"], key_id: int | None = None,
           limits: Limits | None = None) -> Status: ...
@overload
def decode(payload: bytes, kind: Literal["obstacles"], key_id: int | None = None,
           limits: Limits | None = None) -> Obstacles: ...
@overload
def decode(payload: bytes, kind: Literal["snapshot"], key_id: int | None = None,
           limits: Limits | None = None) -> Snapshot: ...
@overload
def decode(payload: bytes, kind: Literal["clock"], key_id: int | None = None,
           limits: Limits | None = None) -> Clock: ...
@overload
def decode(payload: bytes, kind: Literal["config"], key_id: int | None = None,
           limits: Limits | None = None) -> Config: ...
@overload
def decode(payload: bytes, kind: Literal["progress"], key_id: int | None = None,
           limits: Limits | None = None) -> Progress: ...
@overload
def decode(payload: bytes, kind: Literal["run"], key_id: int | None = None, limits: Limits | None = None) -> Run: ...
@overload
def decode(payload: bytes, kind: Literal["estop"], key_id: int | None = None,
           limits: Limits | None = None) -> Estop: ...
@overload
def decode(payload: bytes, kind: Literal["bodies"], key_id: int | None = None,
           limits: Limits | None = None) -> Bodies: ...
@overload
def decode(payload: bytes, kind: Literal["claim"], key_id: int | None = None,
           limits: Limits | None = None) -> Claim: ...
@overload
def decode(payload: bytes, kind: Literal["faultstats"], key_id: int | None = None,
           limits: Limits | None = None) -> FaultStats: ...
@overload
def decode(payload: bytes, kind: Literal["event"], key_id: int | None = None,
           limits: Limits | None = None) -> Event: ...
@overload
def decode(payload: bytes, kind: Literal["proc"], key_id: int | None = None, limits: Limits | None = None) -> Proc: ...
@overload
def decode(payload: bytes, kind: str | None = None, key_id: int | None = None,
           limits: Limits | None = None) -> Message: ...


def decode(payload: bytes, kind: str | None = None, key_id: int | None = None,
           limits: Limits | None = None) -> Message:
    """Validate and decode a payload; `kind` is the expected kind, `key_id` the id in its key, `limits`
    the scenario's bounds (ids, radii, speeds, arena) on top of the physical ones. Raises only
    ProtocolError. The kinds of every control period (state, pose, ref, cmd) go through decoder()."""
    if kind in _HOT_BOUNDS:
        hot = _HOT.get((kind, id(limits)))
        if hot is None or hot[0] is not limits:
            return decoder(kind, limits)(payload, key_id)
        return hot[1](payload, key_id)
    return _decode_checked(payload, kind, key_id, limits)


def _decode_checked(payload: object, kind: str | None, key_id: int | None, limits: Limits | None) -> Message:
    """decode() the general way: every check in turn, with the reason of the first that fails."""
    try:
        msg: Message = _decode(payload, kind, key_id)
        if limits is not None:
            limits.check(msg)
        return msg
    except ProtocolError:
        raise
    except Exception as e:  # never anything but ProtocolError, whatever the bytes (defence in depth)
        raise ProtocolError(f"malformed payload ({type(e).__name__})") from None


def _decode(payload: object, kind: str | None, key_id: int | None) -> Any:
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise ProtocolError(f"payload must be bytes, got {type(payload).__name__}")
    limit = MAX_LARGE_PAYLOAD if kind is None or kind in LARGE_KINDS else MAX_PAYLOAD
    if len(payload) > limit:
        raise ProtocolError(f"payload of {len(payload)} bytes exceeds {limit}")
    try:
        d = _unpackb(payload, raw=False, strict_map_key=True, object_pairs_hook=_unique)
    except _DuplicateKey:
        raise ProtocolError("a map holds a key twice") from None
    except Exception as e:  # msgpack raises several types for garbage
        raise ProtocolError(f"not msgpack: {type(e).__name__}") from None
    if not isinstance(d, dict):
        raise ProtocolError(f"payload must be a map, got {type(d).__name__}")
    fast = _FAST.get(kind) if kind is not None else None
    if fast is None and kind in _SPEC:
        fast = _FAST[kind] = _compile_fast(kind)
    if fast is not None:
        msg = fast(d)
        if msg is not None:
            check = _CHECK.get(kind)
            if check is not None:
                check(msg)
            if key_id is not None and kind in ("state", "config") and msg.id != key_id:
                raise ProtocolError(f"id {msg.id} in the payload does not match id {key_id} in the key")
            return msg
    return _decode_map(d, kind, key_id)


def _decode_map(d: dict[str, Any], kind: str | None, key_id: int | None) -> Any:
    """The general path: every check in turn, with a reason for the first that fails."""
    msg: Any
    if type(d.get("v")) is not int or d.get("v") != VERSION:
        raise ProtocolError(f"unsupported protocol version {str(d.get('v'))[:20]} (this side speaks {VERSION})")
    k = d.get("kind")
    if not isinstance(k, str) or k not in KINDS:
        raise ProtocolError(f"unknown kind {str(k)[:40]!r}")
    if kind is not None and k != kind:
        raise ProtocolError(f"expected kind {kind!r}, got {k!r}")
    if k == "obstacles":
        msg = _obstacles(d)
    elif k == "bodies":
        msg = _bodies(d)
    elif k == "event":
        msg = _event(d)
    elif k == "snapshot":
        msg = _snapshot(d)
    else:
        spec = _SPEC[k]
        _spec_fields(d, k)
        msg = KINDS[k](**{_FIELD.get(n, n): _READ[t](d, n) for n, t in spec if n in d})
        _CHECK.get(k, lambda m: None)(msg)
    if key_id is not None and k in ("state", "config") and msg.id != key_id:
        raise ProtocolError(f"id {msg.id} in the payload does not match id {key_id} in the key")
    return msg


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

_SNAP_FIELDS = ("id", "x", "y", "theta", "v", "w", "stopped", "alive")


# --------------------------------------------------------------------------- the hot path

# The kinds every robot (or the world) decodes every control period, with the physical bounds of their
# _CHECK functions: |field| <= bound (which also says finite); a state also has 0 < r < R.
_HOT_BOUNDS: dict[str, tuple[tuple[str, float], ...]] = {
    "state": (("t", MAX_TIME), ("x", MAX_COORD), ("y", MAX_COORD), ("theta", MAX_ANGLE), ("R", MAX_COORD),
              ("stop", MAX_COORD), ("still", MAX_TIME)),
    "pose": (("t", MAX_TIME), ("x", MAX_COORD), ("y", MAX_COORD), ("theta", MAX_ANGLE), ("cmd", MAX_TIME)),
    "ref": (("t", MAX_TIME), ("x", MAX_COORD), ("y", MAX_COORD), ("theta", MAX_ANGLE), ("v", MAX_SPEED),
            ("w", MAX_TURN)),
    "cmd": (("t", MAX_TIME), ("v", MAX_SPEED), ("w", MAX_TURN), ("until", MAX_TIME)),
}
_ABSENT = object()  # an optional field the map leaves out (an explicit nil is a wrong type, refused)
_HOT: dict[tuple[str, int], tuple[Limits | None, Decoder[HotMessage]]] = {}  # (kind, id(limits)) -> (limits, decoder)


@overload
def decoder(kind: Literal["state"], limits: Limits | None = None) -> Decoder[State]: ...
@overload
def decoder(kind: Literal["pose"], limits: Limits | None = None) -> Decoder[Pose]: ...
@overload
def decoder(kind: Literal["ref"], limits: Limits | None = None) -> Decoder[Ref]: ...
@overload
def decoder(kind: Literal["cmd"], limits: Limits | None = None) -> Decoder[Cmd]: ...
@overload
def decoder(kind: str, limits: Limits | None = None) -> Decoder[HotMessage]: ...


def decoder(kind: str, limits: Limits | None = None) -> Decoder[HotMessage]:
    """f(payload, key_id=None): decode(payload, kind, key_id, limits) for a kind of every control period
    (state, pose, ref, cmd), as one generated function: the payload unpacked once, every field's type,
    bound and limit checked in one expression, the message built without a dataclass __init__. It
    accepts exactly what decode() accepts of those kinds, but for numbers sent as ints: anything it does
    not accept at once goes the general way (_decode_checked), which says what is wrong, or converts.
    Generated once per kind and Limits (a process has one or two; kept while they live)."""
    hot = _HOT.get((kind, id(limits)))
    if hot is not None and hot[0] is limits:
        return hot[1]
    if len(_HOT) >= 64:  # limits of ended runs: let them go
        _HOT.clear()
    f = _HOT[(kind, id(limits))] = (limits, _compile_hot(kind, limits))
    return f[1]


def _compile_hot(kind: str, limits: Limits | None) -> Decoder[HotMessage]:
    spec = _SPEC[kind]
    cls = KINDS[kind]
    optional = _OPTIONAL.get(kind, ())
    var = {_FIELD.get(n, n): f"a{i}" for i, (n, _) in enumerate(spec)}  # python name -> local
    types = {"n": "float", "i": "int", "id": "int", "b": "bool"}
    ns: dict[str, Any] = {"unpackb": _unpackb, "entries": _entries, "slow": _decode_checked, "new": object.__new__,
                          "setattr": object.__setattr__, "cls": cls, "limits": limits, "ABSENT": _ABSENT}

    def may_lack(name: str, test: str) -> str:  # an optional field may be absent: its test then holds
        return f"({var[name]} is ABSENT or {test})" if _WIRE.get(name, name) in optional else test

    cond = [may_lack(_FIELD.get(n, n), f"type({var[_FIELD.get(n, n)]}) is {types[t]}") for n, t in spec]
    for n, t in spec:
        if t in ("i", "id"):
            cond.append(f"0 <= {var[_FIELD.get(n, n)]} <= {MAX_ROBOTS - 1 if t == 'id' else 2**53}")
    for i, (name, bound) in enumerate(_HOT_BOUNDS[kind]):
        ns[f"B{i}"] = bound
        cond.append(may_lack(name, f"-B{i} <= {var[name]} <= B{i}"))
    if kind == "state":
        cond.append(f"0 < {var['r']} < {var['R']}")
        cond.append(may_lack("stop", f"0.0 <= {var['stop']}"))
    if limits is not None:
        tol = 1 + 1e-9  # as Limits.check
        ns.update(ROBOTS=limits.robots, RADIUS=limits.radius * tol, VMAX=limits.v_max * tol,
                  WMAX=limits.w_max * tol)
        if kind == "state":
            cond += [f"{var['id']} < ROBOTS", f"{var['R']} <= RADIUS"]
        if kind == "cmd":
            cond += [f"abs({var['v']}) <= VMAX", f"abs({var['w']}) <= WMAX"]
        if limits.bounds is not None and kind in ("state", "pose"):
            ns["XMIN"], ns["XMAX"], ns["YMIN"], ns["YMAX"] = limits.bounds
            cond += [f"XMIN <= {var['x']} <= XMAX", f"YMIN <= {var['y']} <= YMAX"]
    if kind == "state":
        cond.append(f"(key_id is None or {var['id']} == key_id)")
    if "__slots__" not in cls.__dict__:
        raise TypeError(f"{cls.__name__}: a kind of every control period is a slotted dataclass")
    ns.update({f"_set_{name}": cls.__dict__[name].__set__ for name in var})
    build = ["                m = new(cls)", *[f"                _set_{name}(m, {a})" if _WIRE.get(name, name) not in optional
                                                 else f"                _set_{name}(m, None if {a} is ABSENT else {a})"
                                                 for name, a in var.items()]]
    # the map has exactly the fields of the spec, but the optional ones it leaves out: its size says how many
    size = f"{len(spec) + 2 - len(optional)}" + "".join(f" + ({o!r} in d)" for o in optional)
    body = ["def dec(payload, key_id=None):",
            f"    if type(payload) is bytes and len(payload) <= {MAX_PAYLOAD}:",
            "        try:",
            "            d = unpackb(payload, raw=False, strict_map_key=True)",
            "        except Exception:",
            f"            return slow(payload, {kind!r}, key_id, limits)",
            f"        if type(d) is dict and d.get('kind') == {kind!r} and len(d) == {size} and "
            f"type(d.get('v')) is int and d['v'] == {VERSION} and entries(payload) == len(d):",
            "            try:",
            *[f"                {var[_FIELD.get(n, n)]} = d[{n!r}]" for n, _ in spec if n not in optional],
            "            except KeyError:",
            f"                return slow(payload, {kind!r}, key_id, limits)",
            *[f"            {var[_FIELD.get(n, n)]} = d.get({n!r}, ABSENT)" for n, _ in spec if n in optional],
            "            if " + " and ".join(cond) + ":",
            *build,
            "                return m",
            f"    return slow(payload, {kind!r}, key_id, limits)"]
    exec(compile("\n".join(body), f"<protocol hot decoder for {kind}>", "exec"), ns)
    dec: Decoder[HotMessage] = ns["dec"]
    return dec if _wire is None else _compile_wire(kind, limits, dec)


def _compile_wire(kind: str, limits: Limits | None, fallback: Decoder[HotMessage]) -> Decoder[HotMessage]:
    """The compiled decoder (swarm/proto/_wire.c) of the same conditions as _compile_hot's, on the canonical
    layout only (the encoder's keys in its order, float64 numbers): anything else goes to fallback."""
    order = _wire_order(kind)
    at = {wire: i for i, (wire, _, _) in enumerate(order)}
    conds = [(_wire.IMAX, i, i, 0.0, 0.0, MAX_ROBOTS - 1 if t == "id" else 2**53)
             for i, (_, t, _) in enumerate(order) if t in ("i", "id")]

    def rng(wire: str, lo: float, hi: float) -> None:
        conds.append((_wire.RANGE, at[wire], at[wire], lo, hi, 0))

    for name, bound in _HOT_BOUNDS[kind]:
        rng(_WIRE.get(name, name), -bound, bound)
    if kind == "state":
        conds += [(_wire.GT0, at["r"], at["r"], 0.0, 0.0, 0), (_wire.LT, at["r"], at["R"], 0.0, 0.0, 0)]
        rng("stop", 0.0, MAX_COORD)
    if limits is not None:
        tol = 1 + 1e-9  # as Limits.check and _compile_hot
        if kind == "state":
            if limits.robots < 1:
                return fallback  # no id is in the scenario: the fallback says so
            conds.append((_wire.IMAX, at["id"], at["id"], 0.0, 0.0, limits.robots - 1))
            rng("R", -math.inf, limits.radius * tol)
        if kind == "cmd":  # abs(a) <= b, as a range
            rng("vel", -(limits.v_max * tol), limits.v_max * tol)
            rng("w", -(limits.w_max * tol), limits.w_max * tol)
        if limits.bounds is not None and kind in ("state", "pose"):
            xmin, xmax, ymin, ymax = limits.bounds
            rng("x", xmin, xmax)
            rng("y", ymin, ymax)
    dec: Decoder[HotMessage] = _wire.Decoder(kind, VERSION, order, conds, at["id"] if kind == "state" else -1,
                                             MAX_PAYLOAD, KINDS[kind], fallback)
    return dec


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


REFUSALS_PER_S_MAX = 1_000_000  # messages a process can refuse in a second of wall time (each costs it a
# microsecond or more of decoding): the most a robot's own `bad` counter can have grown by in that time


class Claims:
    """What the robots say they refused (their statuses' `bad`), each bounded by what that robot can have
    seen: its counter grows at most REFUSALS_PER_S_MAX a second of the receiver's wall time since the robot's
    previous status (plus one second), so one status claiming 2^53 does not reach the metrics. A lower count
    is taken as is (a restarted process counts from zero again). `total` is what the run reports."""

    def __init__(self) -> None:
        self.by_robot: dict[int, int] = {}
        self._mono: dict[int, float] = {}
        self.capped = 0  # statuses whose claim was cut to the bound

    def take(self, i: int, bad: int, mono: float) -> None:
        prev, last = self.by_robot.get(i, 0), self._mono.get(i)
        bound = prev + int(REFUSALS_PER_S_MAX * ((0.0 if last is None else max(0.0, mono - last)) + 1.0))
        if bad > bound:
            self.capped += 1
            bad = bound
        self.by_robot[i], self._mono[i] = bad, mono

    def values(self) -> ValuesView[int]:
        return self.by_robot.values()

    @property
    def total(self) -> int:
        return sum(self.by_robot.values())


class BadMessages:
    """Counts refused messages and logs them, at most one line per `every` seconds. A message is counted once
    by each process that refuses it (a state refused by the 6 robots that hear it counts 6 in a run's
    `bad_messages`, which adds the robots' own counts to the world's).

    count: bad messages (malformed, out of bounds, a jump beyond a sender's window, a key that names
    no robot of the scenario); stale: older than what the receiver has from that sender (not
    adopted); duplicates: the same (t, seq) again. Only `count` is what a run reports as bad."""

    def __init__(self, log: logging.Logger, every: float = 5.0):
        self.log = log
        self.every = every
        self.count = 0
        self.stale = 0
        self.duplicates = 0
        self._last = -math.inf
        self._quiet = 0

    def reject(self, key: str, err: Exception) -> None:
        self.count += 1
        now = time.monotonic()
        if now - self._last >= self.every:
            more = f" ({self._quiet} more since the last report)" if self._quiet else ""
            self.log.warning("dropped a bad message on %s: %s%s", key, err, more)
            self._last = now
            self._quiet = 0
        else:
            self._quiet += 1

    def verdict(self, key: str, verdict: str, what: str = "") -> bool:
        """Account for a window's verdict (swarm.proto.window); True if the message is to be adopted."""
        if verdict == "ok":
            return True
        if verdict == "stale":
            self.stale += 1
        elif verdict == "duplicate":
            self.duplicates += 1
        elif verdict == "forged":
            self.reject(key, ProtocolError(f"{what or 'seq or t'}: lock-step, and t is not seq x dt (its tick's time)"))
        else:
            self.reject(key, ProtocolError(f"{what or 'seq or t'} jumps beyond the sender's window"))
        return False

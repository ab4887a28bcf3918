"""The messages of docs/protocol.md, one frozen msgspec struct per kind (built in a tenth of a microsecond, compared
and hashed by value; msgspec.structs.replace makes a changed copy), and ProtocolError, the error of a message that
must not reach the law. swarm.proto.protocol encodes and decodes them through each kind's wire struct. A message of
numbers and strings alone is not tracked by the garbage collector (gc=False: it can hold no cycle)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import msgspec

from swarm.core.errors import SwarmError

if TYPE_CHECKING:
    from typing import TypeAlias


class ProtocolError(SwarmError, ValueError):
    """A message that must not reach the law: the reason says what was wrong."""


class Ref(msgspec.Struct, frozen=True, gc=False):
    """The leader's live reference (leader -> agents)."""

    t: float
    seq: int
    x: float
    y: float
    theta: float
    v: float
    w: float


class Pose(msgspec.Struct, frozen=True, gc=False):
    """A robot's pose (world or localization -> agent)."""

    t: float
    seq: int
    x: float
    y: float
    theta: float
    # real time, optional (None: absent): the t of the newest command the drive executes now (the command's own t,
    # the time of the pose it answered; < 0: none yet): a robot sees how long its commands take to act
    cmd: float | None = None


class Cmd(msgspec.Struct, frozen=True, gc=False):
    """A robot's command (agent -> world or drive)."""

    t: float
    seq: int
    v: float
    w: float
    # real time: the swarm-clock time [s] until which a drive may execute this command; then it brakes along
    # its ramp (docs/runtime.md, "The safety invariant"). Optional on the wire: None (absent) means the
    # drive's own rule (the period the command was meant for and one more, then the ramp).
    until: float | None = None


class State(msgspec.Struct, frozen=True, gc=False):
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


class Status(msgspec.Struct, frozen=True, gc=False):
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


class Obstacle(msgspec.Struct, frozen=True, gc=False):
    x: float
    y: float
    r: float
    R: float


class Obstacles(msgspec.Struct, frozen=True):
    """The world's static obstacles (reply of the obstacles queryable)."""

    obstacles: tuple[Obstacle, ...]


class RobotSnap(msgspec.Struct, frozen=True, gc=False):
    id: int
    x: float
    y: float
    theta: float
    v: float
    w: float
    stopped: bool
    alive: bool


class Snapshot(msgspec.Struct, frozen=True):
    """Every robot at one tick (world -> viewers, recorder)."""

    t: float
    seq: int
    robots: tuple[RobotSnap, ...]


class Clock(msgspec.Struct, frozen=True, gc=False):
    """The world's clock (world -> leader, agents; an extension key). Lock-step: tick seq at time t
    (clock 0 also says every robot's first state has been delivered). Real time: t = (unix time -
    epoch) * speed, so every process can run the same simulated clock from its own wall clock."""

    t: float
    seq: int
    epoch: float  # unix time [s] of t = 0 in real time; 0.0 in lock-step
    speed: float  # simulated seconds per wall second (> 0)


class Config(msgspec.Struct, frozen=True, gc=False):
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


class Body(msgspec.Struct, frozen=True, gc=False):
    id: int
    x: float
    y: float
    r: float
    R: float


class Bodies(msgspec.Struct, frozen=True):
    """Lock-step under faults (world -> every agent, each tick before its poses): the static bodies at
    tick seq, robots that are dead or stopped by the watchdog, where they stand (every agent takes them
    as bodies, neighbours or not); and the robots returning at seq (restarted or resumed: their first
    pose, which is their state of that tick, so nobody waits for it)."""

    t: float
    seq: int
    bodies: tuple[Body, ...]
    returning: tuple[Body, ...] = ()


class FaultStats(msgspec.Struct, frozen=True, gc=False):
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


class Estop(msgspec.Struct, frozen=True, gc=False):
    """The emergency stop (operator -> every drive): engaged, every robot holds zero velocity until a
    release (engaged false). t is the operator's unix time [s], seq its counter (unix time in ms)."""

    t: float
    seq: int
    engaged: bool
    reason: str


class Proc(msgspec.Struct, frozen=True, gc=False):
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


class Run(msgspec.Struct, frozen=True, gc=False):
    """A run's identity (world -> everyone, and the world's run queryable): a new id at every run's
    start; digest = sha256 of the resolved scenario (faults included) as canonical TOML. The
    queryable's reply also carries that TOML in `scenario` (so a robot can name the first
    difference from its own); the publication leaves it empty."""

    run: str
    digest: str
    robots: int
    lockstep: bool
    scenario: str


class Progress(msgspec.Struct, frozen=True, gc=False):
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


class Event(msgspec.Struct, frozen=True):
    """A fault or supervision event (world, swarm up -> viewers, recorders; world/events): a scheduled
    process event of the robots named (kill, restart, hang, resume), a partition that begins or ends
    (robots: every robot cut off from the world's group), or a signal the supervisor sent (signal)."""

    t: float  # simulated time [s]
    seq: int  # the tick (lock-step) or period (real time)
    event: str  # one of EVENTS
    robots: tuple[int, ...]
    detail: str


class Claim(msgspec.Struct, frozen=True, gc=False):
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


KINDS: dict[str, type[Message]] = {"ref": Ref, "pose": Pose, "cmd": Cmd, "state": State, "status": Status,
                                   "obstacles": Obstacles, "snapshot": Snapshot, "clock": Clock, "config": Config,
                                   "progress": Progress, "run": Run, "estop": Estop, "bodies": Bodies, "claim": Claim,
                                   "faultstats": FaultStats, "event": Event, "proc": Proc}
_KIND_OF = {cls: kind for kind, cls in KINDS.items()}


def kind_of(msg: Message) -> str:
    """The kind of a message ("state", "pose", ...), as it goes on the wire."""
    return _KIND_OF[type(msg)]

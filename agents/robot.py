"""The robot agent: one robot's decentralized controller, run as its own process.

It knows only what it hears on the bus:
  robot/<id>/pose     its own pose (from the world now, from localization on a real robot)
  leader/ref          the leader's reference
  cell/<cx>/<cy>/*    the states of the robots in the 3x3 cells around its own
  world/obstacles     the static obstacles (queried once; those within range are used)
  world/clock         the clock (lock-step ticks, or the real-time epoch)
  alive/robot/*       liveliness: a robot that disappears stays a static body at its last pose
and publishes its state on its cell key, its command on robot/<id>/cmd (reliable) and a status.
The law is swarm.core.law.robot_command, the very function `swarm sim` compiles, run here without
numpy or numba (a robot process starts fast and stays small): compiled from its C transcription where
setup.py built it (swarm.core.fastlaw: the same bits, tested), else as plain Python. This module
imports nothing of the world: the same agent drives a simulated or a real robot.

Lock-step tick k (the world owns the clock; docs/runtime.md):
  1. pose_k arrives: move the cell subscriptions (the old block is kept one more tick) and
     publish state_k on the cell key.
  2. Wait for state_k of every live robot whose state_(k-1) was within reach + 2L, where
     reach is the largest R (the law ignores bodies farther than that) and L = (side - reach) / 3
     is the largest step the protocol assumes (a robot that can matter at k, closer than reach,
     was within reach + 2L at k-1; one that was that close is still inside the cells subscribed
     at k-1, so its state_k is sure to arrive), for ref_k and for clock_k (clock_0 is the world's
     start barrier: every state_0 has been delivered). After `wait_timeout` seconds it goes on
     with what it has and counts the missing as stale. A robot that moves more than L in a tick
     breaks the premise; the world then counts the pairs the rule could not cover (metrics
     `lockstep_overruns`): only then can a run differ from swarm sim.
  3. Compute cmd_k from the bodies closer than the cell side in ascending id order (the
     simulator's order: robots by id, then obstacles, then dead robots as static bodies; the
     law uses those closer than reach) and publish it.
Real time: for every new pose it takes the newest reference (advanced exactly along the
leader's arc to now on its own clock) and neighbour states, and publishes state and command; the
command carries the time of the pose it was computed from. States and references wait in bus
inboxes (zenoh ring channels) and the loop decodes them in one batch at each pose: zenoh's thread
runs no Python for them and never waits for the robot's GIL (docs/performance.md, "Tried and dropped"). What it
does without a message (docs/faults.md): it keeps the last state of every live neighbour with its age (the time since
receipt on its own clock plus the age the state had when it came) and never forgets a live one; the
law's governor takes each body's age off its clearance (older than STALE_AFTER_S also counts as
stale in the status); a robot whose liveliness token goes is a static body at its last state; without
a reference it advances the last one along the leader's arc; with a drive whose poses come once a
control period (the simulated world's), a pose that has not come POSE_LATE_PERIODS periods after the
last one is taken as lost: it advances its last pose by its own last command and commands from there.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from typing import TYPE_CHECKING, cast

from swarm.proto import keys, protocol
from agents.control import Controller
from swarm.core import kinematics, law, safety
from swarm.core import runid
from swarm.core.clock import WALL, said_step
from swarm.process import name_thread, settle_heap
from agents.follow import NoAnswer, RunFollower, check_run, query_until  # noqa: F401  (NoAnswer: for callers)
from agents.guard import REF_TIMEOUT_S, Guard, arena_of
from swarm.proto import window
from swarm.proto.protocol import Cmd, Config, Limits, ProtocolError, State, Status
from swarm.core.wake import Runner, Wake
from swarm.net import presence
from swarm.net.bus import drainer
from swarm.core.errors import SwarmError

if TYPE_CHECKING:
    from swarm.drives.base import Drive
    from collections.abc import Callable

    from agents.faultview import FaultView
    from swarm.net.bus import Closable, Inbox

log = logging.getLogger("swarm.robot")

WAIT_TIMEOUT_S = 1.0  # lock-step: wall seconds to wait for a tick's inputs before going on without them
STATUS_PERIOD_S = 0.1  # simulated seconds between status messages
RT_BODIES_TTL_S = 1.0  # real time under faults: a list of still robots older than this [simulated s] is dropped
STALE_AFTER_S = 0.5  # real time: a neighbour state older than this (simulated s) counts as stale (status)
KEY_IDS_MAX = 4096  # cell keys whose robot id a robot keeps parsed (more: it starts over)
CLOSE_WAIT_S = 5.0  # lock-step inline: how long close() waits for a tick under way on a bus thread
HINTS_PER_TICK = 64  # new cell keys a robot hints to its bus a tick, at most (Agent._hint_keys)
GAP_PERIODS = 3  # real time: control periods a near neighbour's states may be missing in a row (losses)
RECENT_S = 1.0  # real time: the states received this recently [simulated s] say how old this robot's news may be
DEPART_S = 4.0  # real time: after a robot moves to another cell, every DEPART_EVERY-th of its states goes to the
# cells it left this long too [simulated s], so a robot that heard it there learns that it left (docs/runtime.md,
# "The safety invariant": knowledge); not every one: on a lossy link each message more makes TCP stall more often
DEPART_EVERY = 10
PROBE_S = 3.0  # real time: a neighbour kept but not heard this long [simulated s] is listened for in every cell
HEAR_GAP_PERIODS = 3  # real time: poses this many periods apart (wall), or a pose missing, is a gap in its hearing
STAND_BELOW = 1e-3  # m/s: real time: a robot the safety rule allows less than this stands and promises to
POSE_LATE_PERIODS = 1.5  # real time, periodic poses: a pose this many periods after the last one is lost
LISTEN_PERIODS = 3  # real time: control periods a robot listens (commands 0) after its first pose
WATCHDOG_S = 0.5  # the world's (or a drive's) watchdog: the windows on t and seq cover twice that, at least 2 s


def block(cx: int, cy: int) -> set[tuple[int, int]]:
    """The 3x3 cells around cell (cx, cy)."""
    return {(cx + a, cy + b) for a in (-1, 0, 1) for b in (-1, 0, 1)}


class DriveRefused(SwarmError, RuntimeError):
    """A drive that cannot serve this run (a ROS 2 robot in a lock-step run)."""


class Agent:
    """One robot's controller on a bus; it subscribes and publishes on its own (start(), then a loop).

    Thread model: bus callbacks (the _on_*_msg methods) run on the bus's receiving thread: they
    validate the message, update what the agent knows under `lock`, and set `kick` when there is
    something to do (a new tick, or a tick whose inputs are complete). By default `kick` is `wake`, the
    loop thread's, and the loop thread does every bus call (publish, move subscriptions, drain inboxes).
    Inline (no faults, on zenoh: run_robot), `kick` is a Runner that computes the tick on the callback's
    own thread at once (lock-step; in real time the simulated drive's pose callback runs the step): no
    loop thread woken for it (docs/performance.md, "A tick on the thread its message came on"); the loop thread then only closes the subscriptions a tick
    let go (_release) and computes a lock-step tick that is overdue.
    Lock-step takes everything through callbacks (its wait rule needs each state as it arrives); its
    neighbour states through a compiled sink where it was built (swarm.proto._wire.StateSink: the same
    rules as _on_state_msg, which gets anything but their common case). Real time uses callbacks only
    for liveliness and the clock: the loop blocks on its pose inbox and drains the reference and cell
    inboxes itself (take_poses, _take_inboxes).
    """

    def __init__(self, bus, cfg: Config, fleet: str = "default", wait_timeout: float = WAIT_TIMEOUT_S,
                 clock=WALL, drive: Drive | None = None, guard=None, faults=None, counters=None, inline: bool = False,
                 partitions=(), law_file: str | None = None):
        """inline (zenoh's bus, no faults): a lock-step tick runs on the bus thread whose message made it due
        (its pose, the last state it waited for), and a real-time step on the thread of its simulated drive's
        pose, instead of waking the loop thread for it (`kick`, a swarm.core.wake.Runner; only on a bus that
        calls another session's messages on threads of its own: zenoh's).
        Real time: counters, when given, is an object with `dropped` and `delayed` lists by class (a
        swarm.net.faultbus.FaultBus): reported to the world with every status; partitions, the run's
        (swarm.core.faults.Partition): a neighbour cut off by one is never taken as away while it lasts. law_file: where
        this machine keeps the file of the run's law, when not where the run's config says (swarm robot --law-file)."""
        self.bus, self.cfg, self.fleet = bus, cfg, fleet
        self.id = cfg.id
        self.clock = clock
        self.wait_timeout = wait_timeout
        # real time: where this robot meets its body (swarm.drives: the simulated world's keys by default,
        # or a ROS 2 robot) and the robot-side watchdog (agents.guard); lock-step is simulation only
        if drive is None and not cfg.lockstep:
            from swarm.drives.sim import SimDrive

            drive = SimDrive(bus, fleet, cfg.id)
        self.drive = drive
        self._pose_key = drive.pose_key if drive is not None else "pose"  # where a bad pose is said to come from
        self.guard = guard
        self.periodic = drive is not None and drive.periodic  # its poses come once a control period
        # the law: the paper's, or the user's the run names (agents.control); its parameters and memory
        self.control = Controller(cfg, law_file)
        self.p = self.control.p
        self._law = self.control.command
        # lock-step under faults: the receiving side's fault layer decides what the law is given
        # (agents.faultview, the simulator's rules); the governor's horizon covers a held command
        self.view: FaultView | None = None
        self.static_by_seq: dict[int, dict[int, tuple[float, float, float, float]]] = {}
        if faults and cfg.lockstep:
            from agents.faultview import FaultView
            from swarm.core.faultsim import horizon

            self.view = FaultView(cfg.id, cfg.robots, cfg.dt, cfg.reach, cfg.sense, faults)
            self.p[law.P_DT] = horizon(faults, cfg.dt)
        self.mem = self.control.fresh_memory()
        self.side = cfg.sense
        self._wait_reach = keys.lockstep_wait_reach(cfg.reach, cfg.sense)
        self._cmd_key, self._status_key = keys.robot_cmd(fleet, self.id), keys.robot_status(fleet, self.id)
        self._ref_key = keys.leader_ref(fleet)
        self._ref_inbox: Inbox  # real time: the reference's inbox (start)
        self._faults_key = keys.robot_faults(fleet, self.id)
        self.lock = threading.Lock()
        self.wake = Wake()  # the loop thread's
        # what a callback sets when the loop has work (or, inline, runs that work: __init__)
        self.kick: Wake | Runner = self.wake
        self._closing: dict[object, Closable] = {}  # inline: subscriptions the loop thread is to close (_release)
        self._closing_lock = threading.Lock()
        self.table: dict[int, State] = {}  # the last state of every robot heard (alive: not in self.dead)
        self.dead: set[int] = set()
        self.obstacles: list[tuple[float, float, float, float]] = []
        self._ocells: dict[tuple[int, int], list[int]] = {}
        self._onear: dict[tuple[int, int], list[tuple[float, float, float, float]]] = {}
        self.pose: protocol.Pose | None = None
        self.refs: dict[int, protocol.Ref] = {}  # lock-step: by seq
        self.ref: protocol.Ref | None = None  # newest
        self.clock_seq = -1
        self.epoch: float | None = None
        self.speed = 1.0
        self.bad = protocol.BadMessages(log)
        # what this robot accepts: the scenario's ids and radii (swarm.proto.protocol.Limits), and from each
        # sender only times and sequence numbers that move forward within a window (swarm.proto.window)
        self.limits = Limits.of(cfg.robots, cfg.reach)
        self._vb = cfg.v_max if cfg.v_max > 0 else law.MAX_SPEED  # the speed bounds a command is held within
        self._wb = cfg.w_max if cfg.w_max > 0 else law.MAX_TURN
        self._dec_state, self._dec_ref = protocol.decoder("state", self.limits), protocol.decoder("ref", self.limits)
        self._enc_state, self._r, self._R = protocol.encoder("state"), cfg.r, cfg.R
        self._hot_dec = {"state": self._dec_state, "ref": self._dec_ref, "pose": protocol.decoder("pose", self.limits)}
        self._key_ids: dict[str, int] = {}  # cell key -> the robot id at its end (parsed once)
        if inline and self.view is None and counters is None and (cfg.lockstep or (drive is not None and drive.takes_callback)):
            self.kick = Runner(self._ticks if cfg.lockstep else self._step_inline, self.wake)
        # real time: the step without a pose's deadline, for the waker to wait on without the GIL (_watch)
        wire = protocol._wire
        self.late_timer = wire.Deadline() if wire is not None and not cfg.lockstep and \
            getattr(clock, "machine_monotonic", False) else None
        self._rt_poses: deque = deque()  # real time inline: poses the drive's callback handed over, not taken yet
        # lock-step, no faults: neighbour states taken in C on the bus's thread (swarm/proto/_wire.c, StateSink;
        # anything but the common case goes to _on_state_msg)
        self._state_sink = wire.StateSink(self, self._dec_state, self._key_ids, self._on_state_msg, self._sink_error) \
            if wire is not None and cfg.lockstep and self.view is None and hasattr(bus, "subscribe_sink") else None
        if self.drive is not None and self.drive.limits is None:
            self.drive.limits = self.limits  # the simulated drive decodes poses with the scenario's bounds
        self._spans = window.spans(cfg.dt, WATCHDOG_S)
        self._tick = cfg.dt if cfg.lockstep else 0.0  # lock-step: a pose's, reference's, state's t is seq x dt
        self.w_pose = window.Window(*self._spans, dt=self._tick)  # the world (or localization)
        self.w_clock = window.Window(*self._spans, dt=self._tick)  # the world
        self.w_ref = window.Window(*self._spans, dt=self._tick)  # the leader
        self.w_bodies = window.Window(*self._spans)  # the world (real time under faults)
        self.w_state: dict[int, window.Window] = {}  # robot j
        self.ended = False  # the run this agent serves is over (a new run began): ignore everything
        self.belief: protocol.Pose | None = None  # lock-step under faults: its pose as it knows it at the tick
        self.w_estop = window.Window(math.inf, 2**62)  # the operator's: forward only (its clock is unix time)
        self.estopped: str | None = None
        self.leader_alive = False
        self.leader_ups = 0  # times the leader's token appeared (a restarted leader during a tick)
        self._leader_ups_seen = 0
        # lock-step tick state
        self.k_done = -1
        self.k_started = -1
        self.waiting: set[int] = set()
        self.deadline = 0.0
        self.prev_xy: tuple[float, float] | None = None
        # counters
        self.refs_taken = 0
        self.states_received = 0
        self.loop_cpu_s = 0.0  # CPU time of the loop thread handling its wake-ups (thread_time; bench/up_speed.py)
        self.process_cpu_s = 0.0  # CPU time of the whole process (zenoh's threads too) while its loop ran
        self.ticks = 0
        self.skipped = 0
        self.stale_total = 0
        self.seq = 0
        self._last_status_t = -math.inf
        self._cells: dict[tuple[int, int], Closable] = {}
        self._state_keys: dict[tuple[int, int], str] = {}  # this robot's state key in each cell it has been in
        self._block_prev: set[tuple[int, int]] = set()
        self._cell: tuple[int, int] | None = None
        self._settled = False  # the subscriptions are exactly the block around self._cell
        self._handles: list = []
        self._clock_sub = None
        self.last_cmd: Cmd | None = None
        self.neighbours = 0
        self.stale = 0
        self.oldest_state_s = 0.0  # real time: age of the oldest neighbour state in the last command
        self._first_pose_t: float | None = None
        # real time: what it knows without messages (docs/faults.md, Safe under faults) and the safety rule
        # (swarm.core.safety; docs/runtime.md, "The safety invariant")
        self.counters = counters
        # its poses come through the router as its neighbours' states do, each link in order (zenoh over TCP; no
        # fault bus, which drops and delays messages one by one): a gap in its poses shows where it may miss states
        self._ordered = counters is None and self.periodic
        self.partitions = tuple(partitions)
        self.V = cfg.v_bound  # the speed bound it keeps to and assumes of every other robot
        self.ramp = drive.ramp_s if drive is not None else safety.RAMP_S  # its drive brakes from a command's until along this
        self.switch = drive.switch_s if drive is not None else 0.0  # and takes a new command within this
        self.base_timeout = drive.base_timeout_s if drive is not None else None  # a base acts on a command that long (None: unknown)
        self._pending: deque = deque()  # (|v|, |w|, until) of the commands sent that may still act
        # the high but typical lag of its poses, of its commands (from computing one to its drive executing it)
        # and of its neighbours' states when they come [s]: the commands' validity (swarm.core.safety.validity)
        # and the information delay (_info_delay)
        self._lag, self._act, self._news = safety.Recent(), safety.Recent(), safety.Recent()
        self._sent_at: deque = deque(maxlen=256)  # (the t a command carries, the time it was computed)
        self._still_until = -math.inf  # its promise: no command that moves it before this time
        self._promises = 0
        self._rt_until: float | None = None  # the last command's validity, its state's stop and still
        self._rt_stop = 0.0
        self._rt_still = 0.0
        self.commanded = 0  # real time: commands its law computed (not listening)
        self.held = 0  # of those, the ones the safety rule held back (slowed or stopped)
        self.held_why = [0] * 5  # by what held them (swarm.core.safety: FREE, BODY, AWAY_ONLY, UNKNOWN, PENDING)
        self.forgotten = 0  # neighbours taken as away by the knowledge rule
        self.rx: dict[int, tuple[float, float]] = {}  # j -> (age of its state when it came [s], monotonic receipt)
        self.away: set[int] = set()  # live robots taken as away by the knowledge rule (_rt_bodies): until a newer state
        self._beyond: set[int] = set()  # those of them it took as away when last asked (forgotten counts the new ones)
        self._gaps: deque = deque(maxlen=32)  # real time: the last gaps in its poses, (from, to) monotonic (_missed)
        self._left: dict[str, float] = {}  # real time: key of a cell it left -> until when its states go there too
        self._probes: dict = {}  # real time: j -> an inbox on j's states in every cell (_update_probes)
        self._want_probe: set[int] = set()  # real time: neighbours _rt_bodies kept but has not heard for PROBE_S
        self.max_age = 0.0  # the oldest neighbour state a command used [s]
        self.reports = 0  # faultstats sent
        self._report_lock = threading.Lock()
        self._reported_at = -math.inf  # monotonic time of the last faultstats sent
        self.last_pose_at: float | None = None  # monotonic time the newest pose was taken
        self.reckoned = 0  # commands computed from a pose advanced by its own command (a pose was late)
        self._rt_t = -math.inf  # the time of the last state and command it published
        self._rt_belief: tuple[float, float, float, float] | None = None  # (t, x, y, theta) they were computed at

    # ------------------------------------------------------------------ wiring

    def start(self, obstacles: list[protocol.Obstacle] | None = None) -> None:
        """Subscribe (own pose, reference, clock, liveliness, the cells around the start pose),
        then declare this robot's liveliness token: whoever sees the token can count on them."""
        f = self.fleet
        self.set_obstacles(obstacles or [])
        if self.cfg.lockstep:
            self._inputs = [self.bus.subscribe(key, fn) for key, fn in self._lockstep_inputs()]
        elif isinstance(self.kick, Runner):  # its drive's poses to a callback that runs the step (_step_inline)
            cast("Drive", self.drive).start(self._on_drive_poses)  # real time always has one
            self._poses_by_callback = True
            self._ref_inbox = self.bus.inbox(self._ref_key)
            self._handles.append(self._ref_inbox)
        else:  # the loop waits on its drive's poses and drains the other inboxes (see _loop_realtime)
            cast("Drive", self.drive).start()
            self._ref_inbox = self.bus.inbox(self._ref_key)
            self._handles.append(self._ref_inbox)
        self._handles.append(self.bus.subscribe(keys.estop(f), self._on_estop_msg))
        if not self.cfg.lockstep or self.view is None:  # robots standing still (lock-step under faults: an input)
            self._handles.append(self.bus.subscribe(keys.world_bodies(f), self._on_bodies_msg))
        if self.view is not None:
            if self.view.returns():
                self._listen_all(True)  # this may be the process of a restart: its first tick may be a return
        self._clock_sub = self.bus.subscribe(keys.world_clock(f), self._on_clock_msg)
        self._handles.append(self.bus.watch_alive(keys.alive_any(f), self._on_alive_msg))
        self._move_cells(self.cfg.x, self.cfg.y)
        self._handles.append(self.bus.token(keys.alive(f, "robot", self.id)))  # its process says who it is: run_robot

    def _lockstep_inputs(self) -> list:
        """Lock-step: (key, handler) of its pose, the reference and, under faults, the static bodies."""
        f = self.fleet
        out = [(keys.robot_pose(f, self.id), self._on_pose_msg), (keys.leader_ref(f), self._on_ref_msg)]
        if self.view is not None:
            out.append((keys.world_bodies(f), self._on_bodies_msg))
        return out

    _inputs: list = []

    def _resubscribe(self) -> None:
        """Lock-step under faults (loop thread): this robot's session came back after a stop past its lease.
        zenoh declares its subscriptions again by itself, but in no order one can count on; declared here
        once more, they are in place before the message that follows them on the same session (which tells
        the world this robot is back: World._await_returns)."""
        f = self.fleet
        for h in self._inputs:
            h.close()
        self._inputs = [self.bus.subscribe(key, fn) for key, fn in self._lockstep_inputs()]
        with self.lock:  # the world and the leader went on meanwhile: their next messages jump ahead
            self.w_pose.reset()
            self.w_ref.reset()
            self.w_clock.reset()
        for c in list(self._cells):
            self._cells.pop(c).close()
            self._cells[c] = self._subscribe_cell(keys.cell_any(f, *c))
        if self._all_sub is not None:
            self._listen_all(False)
            self._listen_all(True)

    def set_obstacles(self, obstacles: list[protocol.Obstacle]) -> None:
        """Keep the obstacles, indexed by cell so a tick looks only at the 3x3 cells around it."""
        self.obstacles = [(o.x, o.y, o.r, o.R) for o in obstacles]
        self.p[law.P_OBSTACLE_R] = max((o.r for o in obstacles), default=0.0)  # the governor's bound (swarm.core.law)
        self._ocells = {}
        self._onear = {}
        for m, (x, y, _r, _R) in enumerate(self.obstacles):
            self._ocells.setdefault(keys.cell_of(x, y, self.side), []).append(m)

    def _obstacles_near(self, cell: tuple[int, int]) -> list[tuple[float, float, float, float]]:
        """The obstacles in the 3x3 cells around `cell`, by index (the simulator's order); kept per cell."""
        near = self._onear.get(cell)
        if near is None:
            idx = sorted(m for c in block(*cell) for m in self._ocells.get(c, ()))
            near = self._onear[cell] = [self.obstacles[m] for m in idx]
        return near

    def end(self) -> None:
        """The run this agent serves is over (any thread): it ignores everything from now on and its
        loop returns."""
        self.ended = True
        self.wake.set()

    def close(self) -> None:
        """Release everything; a drive is halted and closed (on every way out: the end of a run, Ctrl-C,
        SIGTERM, an exception). Inline, no tick runs on a bus thread from here on (after one under way)."""
        if isinstance(self.kick, Runner) and not self.kick.stop(CLOSE_WAIT_S):
            log.warning("robot %d: a tick on the bus's thread still runs after %g s; closing all the same",
                        self.id, CLOSE_WAIT_S)
        self.close_released()
        if self.drive is not None:
            try:
                self.drive.close()
            except Exception as e:  # the session may be gone already: nothing left to tell the body
                log.warning("robot %d: closing the drive: %s", self.id, e)
        self.drop_clock()
        self._listen_all(False)
        for h in self._inputs:
            h.close()
        self._inputs = []
        for h in list(self._cells.values()) + list(self._probes.values()) + self._handles[::-1]:
            h.close()
        self._cells.clear()
        self._probes.clear()
        self._handles.clear()

    def _move_cells(self, x: float, y: float) -> None:
        """Subscribe to the 3x3 cells around (x, y), keeping the previous block one more tick."""
        if len(self._key_ids) != self._hinted_n:
            self._hint_keys()
        cell = keys.cell_of(x, y, self.side)
        if cell == self._cell and self._settled:
            return  # the common case: same cell as last tick, old block already released
        now = block(*cell)
        want = now | self._block_prev
        for c in want - self._cells.keys():
            h = self._reclaim(c)
            if h is None:
                key = keys.cell_any(self.fleet, *c)
                h = self._subscribe_cell(key) if self.cfg.lockstep else self.bus.inbox(key)
            self._cells[c] = h
        for c in self._cells.keys() - want:
            self._release(c, self._cells.pop(c))
        self._drain_cells = None  # real time: remade for the new set of inboxes
        self._settled = cell == self._cell
        self._cell = cell
        self._block_prev = now

    def _update_probes(self) -> None:
        """Real time (loop thread): listen for each neighbour the knowledge rule keeps but has not heard for
        PROBE_S in every cell (`cell/*/*/<j>`): its next state says where it is (in this robot's block: heard
        again; beyond it: away), so a neighbour that left while its states were lost (its cell-leaving copies too)
        does not hold this robot back for good. A probe ends once its robot is heard, away or dead."""
        probes = self._probes
        mono = self.clock.monotonic()
        with self.lock:
            add = [j for j in self._want_probe if j not in probes]
            self._want_probe.clear()
            rx, dead, away, speed = self.rx, self.dead, self.away, self.speed
            drop = [j for j in probes if j in dead or j in away or j not in self.table or
                    (mono - rx.get(j, (0.0, -math.inf))[1]) * speed < PROBE_S]
        for j in drop:
            self._release(("probe", j), probes.pop(j))
        for j in add:
            probes[j] = self.bus.inbox(keys.cell_robot_any(self.fleet, j))
            self.probed += 1
        if add or drop:
            self._drain_cells = None

    probed = 0  # real time: neighbours listened for in every cell (_update_probes)
    rt_static: dict = {}  # real time: id -> (x, y, r, R) of the robots the world lists as standing still (_on_bodies)
    rt_static_t = 0.0  # the simulated time of that list
    _poses_by_callback = False  # real time inline: the drive's callback hands over every pose (drive.drain() has none)
    # real time: drains the reference's and every cell's inbox in one call (swarm.net.bus.drainer)
    _drain_cells: Callable[[], list[tuple[str, bytes]]] | None = None
    # real time, under the lock: _on_states's (now, ahead, mono) for _take_one
    _batch: tuple[float | None, float, float] = (None, math.inf, 0.0)
    _hinted_n = 0  # how many of _key_ids (insertion-ordered; only added to, or cleared) went to bus.hint

    def _hint_keys(self) -> None:
        """Loop thread: the cell keys heard since the last call, hinted to the bus (ZenohBus.hint: zenoh
        resolves each one's route once, not for every state), at most HINTS_PER_TICK a call (a stranger's
        flood of new keys costs a declaration each: never more than that a tick); _move_cells calls it at
        every tick while _key_ids holds keys not hinted yet."""
        ids = list(self._key_ids)  # one C call under the GIL: safe against the compiled sink adding to it
        start = self._hinted_n if len(ids) >= self._hinted_n else 0  # it was cleared (KEY_IDS_MAX): from the top
        new = ids[start:start + HINTS_PER_TICK]
        for key in new:
            self.bus.hint(key)
        self._hinted_n = start + len(new)

    def _subscribe_cell(self, key: str):
        """Lock-step: a cell's states, through the compiled sink where there is one (no faults, a bus that takes
        it, the wire codec built), else through _on_state_msg: the same rules either way."""
        if self._state_sink is None:
            return self.bus.subscribe(key, self._on_state_msg)
        return self.bus.subscribe_sink(key, self._state_sink)

    def _sink_error(self, key: str | None, e: BaseException) -> None:
        """The compiled sink's errors (a message that tripped a bug costs that message): counted and logged."""
        with self.lock:
            self.bad.reject(key or "?", RuntimeError(f"taking a state raised {type(e).__name__}: {e}"))

    @property
    def horizon_s(self) -> float:
        """The safety governor's horizon [s]: the control period, or more in real time (see command())."""
        return self.p[law.P_DT]

    def drop_clock(self) -> None:
        """Unsubscribe from the clock once it has given what this robot needs."""
        if self._clock_sub is not None:
            self._release("clock", self._clock_sub)
            self._clock_sub = None

    def _release(self, what, handle) -> None:
        """Close a subscription that a tick no longer needs: at once on the loop thread; inline, by the loop
        thread, which this wakes. zenoh's undeclare waits for the subscription's callbacks under way, and the
        tick may run in one of them (docs/performance.md, "A tick on the thread its message came on"): closed there, it would wait for itself."""
        if self.kick is self.wake:
            handle.close()
            return
        with self._closing_lock:
            self._closing[what] = handle
        self.wake.set()

    def _reclaim(self, what):
        """A subscription _release is to close that a tick wants again (a cell re-entered): taken back, or None."""
        if not self._closing:
            return None
        with self._closing_lock:
            return self._closing.pop(what, None)

    def close_released(self) -> None:
        """Loop thread: close the subscriptions _release handed over."""
        while self._closing:
            with self._closing_lock:
                what = next(iter(self._closing))
                handle = self._closing.pop(what)
            handle.close()

    @property
    def subscribed_cells(self) -> set[tuple[int, int]]:
        return set(self._cells)

    # ------------------------------------------------------------------ events

    # Bus callbacks, on the bus's thread: decode (outside the lock), update under the lock, and wake
    # the loop if it has work. A bad message is dropped and counted, never raised.

    def _on_state_msg(self, key: str, data: bytes) -> None:
        """Lock-step: a neighbour's state (_receive for the message of every neighbour, every tick)."""
        if self.ended:
            return
        j = self._key_ids.get(key)
        try:
            if j is None:
                j = keys.cell_robot(key)
                if j is None:
                    raise ProtocolError(f"not a cell key: {key!r}")
                if len(self._key_ids) >= 4096:  # keys of robots long gone (or a stranger's): bounded
                    self._key_ids.clear()
                self._key_ids[key] = j
            s = self._dec_state(data, j)
        except ProtocolError as e:
            with self.lock:
                self.bad.reject(key, e)
            return
        with self.lock:
            waited = s.id in self.waiting
            self._on_state(s, key)
            # only the state that took the last awaited robot off can make the tick due (the compiled sink's
            # rule): anything else _due() reads woke the loop when it came (a pose, the reference, a token)
            due = waited and not self.waiting and self._due()
        if due:
            self.kick.set()

    def _on_pose_msg(self, key: str, data: bytes) -> None:
        self._receive(key, data, "pose", None, self._on_pose)

    def _on_ref_msg(self, key: str, data: bytes) -> None:
        self._receive(key, data, "ref", None, self._on_ref)

    def _on_clock_msg(self, key: str, data: bytes) -> None:
        self._receive(key, data, "clock", None, self._on_clock)

    def _on_bodies_msg(self, key: str, data: bytes) -> None:
        self._receive(key, data, "bodies", None, self._on_bodies)

    def _on_bodies(self, b: protocol.Bodies, key: str = "") -> None:
        """Lock-step under faults: the static bodies of tick b.seq (dead or stopped robots), every tick,
        and the robots returning at b.seq: their first pose is their state of that tick (taken as if it
        came from them: nobody waits for a robot that was away at b.seq - 1). Real time under faults: the
        robots standing still (dead, hung, stopped by the watchdog) where they are, each period: static
        bodies for bodies() until the next message (World._publish_bodies_rt)."""
        if not self.cfg.lockstep:
            if self.bad.verdict(key, self.w_bodies.check(b.t, b.seq), "the bodies' t or seq"):
                self.rt_static = {s.id: (s.x, s.y, s.r, s.R) for s in b.bodies if s.id != self.id and s.id < self.cfg.robots}
                self.rt_static_t = b.t
                if any(s.id == self.id for s in b.bodies):  # listed as standing: every robot takes it as static
                    self._still_until = max(self._still_until, b.t + safety.BODIES_HOLD_S)  # until then: so be it
            return
        if self.view is None:  # lock-step without faults: robots lost (token gone) where the world stopped them
            if self.bad.verdict(key, self.w_bodies.check(b.t, b.seq), "the bodies' t or seq"):
                for s in b.bodies:
                    if s.id != self.id and s.id < self.cfg.robots:
                        nb = self.table.get(s.id)
                        self.table[s.id] = State(id=s.id, t=b.t, seq=b.seq if nb is None else nb.seq, x=s.x, y=s.y,
                                                 theta=0.0 if nb is None else nb.theta, r=s.r, R=s.R, frozen=False)
                        self.dead.add(s.id)
                        self.waiting.discard(s.id)
            return
        if b.seq <= self.k_done or b.seq > self._next_tick():
            return  # an old tick's, or one too far ahead (the world publishes a tick's bodies just before its poses)
        self.static_by_seq[b.seq] = {s.id: (s.x, s.y, s.r, s.R) for s in b.bodies if s.id < self.cfg.robots}
        for s in b.returning:
            nb = self.table.get(s.id)
            if s.id != self.id and s.id < self.cfg.robots and (nb is None or nb.seq < b.seq):
                self.table[s.id] = State(id=s.id, t=b.t, seq=b.seq, x=s.x, y=s.y, theta=0.0, r=s.r, R=s.R,
                                         frozen=False)
                if b.seq == self.k_started:
                    self.waiting.discard(s.id)

    def _listen_all(self, on: bool) -> None:
        """Lock-step under faults (loop thread, or start()): hear every robot's state, in every cell, for
        a tick this robot returns at (restarted or resumed, it knows nobody's previous state, so it waits
        for the state of every robot running then)."""
        if on and self._all_sub is None:
            self._all_sub = self.bus.subscribe(keys.cell_all(self.fleet), self._on_any_state_msg)
        elif not on and self._all_sub is not None:
            self._all_sub.close()
            self._all_sub = None

    _all_sub = None

    def _on_any_state_msg(self, key: str, data: bytes) -> None:
        """A state heard through _listen_all: kept only when it is of a tick this robot returns at (its
        cells' subscriptions bring the same message through the windows of _on_state)."""
        if self.ended:
            return
        j = keys.cell_robot(key)
        try:
            if j is None:
                raise ProtocolError(f"not a cell key: {key!r}")
            s = protocol.decode(data, "state", j, self.limits)
        except ProtocolError as e:
            with self.lock:
                self.bad.reject(key, e)
            return
        with self.lock:
            if s.id == self.id or self.view is None:
                return
            if s.seq <= self.k_done or s.seq > self._next_tick() or self.view.schedule.fresh(self.id, s.seq) is None:
                return  # not of a return tick of this robot (or too far ahead): the cells' subscriptions decide
            nb = self.table.get(s.id)
            if nb is None or nb.seq < s.seq:
                self.table[s.id] = s
            if s.seq == self.k_started:
                self.waiting.discard(s.id)
            due = self._due()
        if due:
            self.kick.set()

    def _on_estop_msg(self, key: str, data: bytes) -> None:
        self._receive(key, data, "estop", None, self._on_estop)

    def _on_estop(self, e: protocol.Estop, key: str = "") -> None:
        """The emergency stop: latched by the guard (a real drive halts within a period: the guard's
        thread); a lock-step robot commands zero while it is engaged. Safety first: an engage that decodes
        is always obeyed, whatever its t and seq (a forged message far ahead must never make a later
        stop look old); a release only when it moves forward and is newer than every engage obeyed."""
        verdict = self.w_estop.check(e.t, e.seq)
        if e.engaged:
            if verdict not in (window.OK, window.DUPLICATE):
                self.bad.verdict(key, verdict, "the emergency stop's t or seq")  # counted, and obeyed all the same
            self._estop_seq = max(self._estop_seq, e.seq)
        else:
            if not self.bad.verdict(key, verdict, "the emergency stop's t or seq"):
                return
            if e.seq <= self._estop_seq:
                self.bad.stale += 1  # older than an engage obeyed: the stop holds
                return
        self.estopped = e.reason or "engaged" if e.engaged else None
        if self.guard is not None:
            self.guard.estop(e.engaged, e.reason)

    _estop_seq = -1  # the largest seq of an engaged emergency stop obeyed

    def _on_alive_msg(self, key: str, up: bool) -> None:
        """A liveliness token came or went. A robot's: it is alive, or dead (a static body). A new token
        of the world, the leader or a robot restarts that sender's windows (a restarted process counts
        from 0 again)."""
        parsed = keys.parse(key)
        if parsed is None or parsed.kind != "alive" or parsed.id is None or self.ended:
            return
        with self.lock:
            if parsed.role == "robot":
                if parsed.id == self.id or parsed.id >= self.cfg.robots:
                    return
                self._on_alive(parsed.id, up)
                if up and parsed.id in self.w_state:
                    self.w_state[parsed.id].reset()
            elif parsed.role == "world":
                self.world_alive = up
                if self.guard is not None:
                    self.guard.world(up)  # real time: a robot that lost the world halts, as for a lost leader
                if up:
                    self.w_pose.reset()
                    self.w_clock.reset()
                    self.w_bodies.reset()  # real time: this robot was away (hung past its lease): the list moved on
                    self._world_ups += 1
                    if self.view is not None and self._world_ups > 1:
                        # the world's token again: this robot's session came back (it was stopped past its lease):
                        # say so once its subscriptions are back (they were sent before this could arrive)
                        self._announce = True
                        self.wake.set()
            elif parsed.role == "leader":
                self.leader_alive = up
                if self.guard is not None:
                    self.guard.leader(up)
                if up:
                    self.w_ref.reset()
                    self.leader_ups += 1
            due = self._due()
        if due:
            self.kick.set()

    def _receive(self, key: str, data: bytes, kind: str, key_id: int | None, apply) -> None:
        if self.ended:
            return
        try:
            if kind == "state" and key_id is None:
                raise ProtocolError(f"not a cell key: {key!r}")
            dec = self._hot_dec.get(kind)  # the kinds of every tick: their generated decoders, at once
            msg = dec(data, key_id) if dec is not None else protocol.decode(data, kind, key_id, self.limits)
        except ProtocolError as e:
            with self.lock:
                self.bad.reject(key, e)
            return
        with self.lock:
            apply(msg, key)
            due = self._due()
        if due:
            self.kick.set()

    def take_poses(self, poses: list[protocol.Pose]) -> None:
        """Real time (the step's thread): the poses the drive gave (decoded); each in the window is taken."""
        if not poses:
            return
        key = self._pose_key
        for pose in poses:
            with self.lock:
                self._on_pose(pose, key)
        self.pose_taken(self.clock.monotonic())
        if self.guard is not None:
            self.guard.pose(poses[-1].x, poses[-1].y)

    def _take_inboxes(self) -> None:
        """Real time (loop thread): decode the references and neighbour states waiting in the inboxes,
        in one batch under one lock (no per-message wake-up: the loop is already running)."""
        if not self._poses_by_callback:  # inline, the drive's callback hands every pose to the step: none here
            self.take_poses(cast("Drive", self.drive).drain())  # one that came since the loop woke (the newest wins)
        states: list[tuple[State, str]]
        bad, refs, states = [], [], []
        if self._drain_cells is None:  # the reference's inbox and every cell's in one call (swarm.net.bus.drainer),
            self._drain_cells = drainer([self._ref_inbox, *self._cells.values(), *self._probes.values()])  # remade
            # when the cells or the probes change
        items = self._drain_cells()
        if items and items[0][0] == self._ref_key:  # the reference's come first (its inbox's key is exact)
            n = 1
            while n < len(items) and items[n][0] == self._ref_key:
                n += 1
            dec_ref = self._dec_ref
            for key, data in items[:n]:
                try:
                    refs.append((dec_ref(data), key))
                except ProtocolError as e:
                    bad.append((key, e))
            items = items[n:]
        dec, ids = self._dec_state, self._key_ids
        wire = protocol._wire
        if items and wire is not None:  # the loop below, compiled (swarm/proto/_wire.c)
            wire.decode_states(items, dec, ids, keys.cell_robot, states, bad, ProtocolError, KEY_IDS_MAX)
        elif items:
            for key, data in items:
                j = ids.get(key)
                if j is None:
                    j = keys.cell_robot(key)
                    if j is None:
                        bad.append((key, ProtocolError(f"not a cell key: {key!r}")))
                        continue
                    if len(ids) >= KEY_IDS_MAX:  # keys of robots long gone (or a stranger's): bounded
                        ids.clear()
                    ids[key] = j
                try:
                    states.append((dec(data, j), key))
                except ProtocolError as e:
                    bad.append((key, e))
        with self.lock:
            for ref, key in refs:
                self._on_ref(ref, key)
            if states:
                self._on_states(states)
            for key, err in bad:
                self.bad.reject(key, err)

    def _on_states(self, states: list[tuple[State, str]]) -> None:
        """Real time (under the lock): _on_state for a batch of (state, key), with one reading of the clocks."""
        now = self.sim_time(self.clock.time())
        ahead = math.inf if now is None else now + self._spans[0]
        mono = self.clock.monotonic()
        self._batch = (now, ahead, mono)
        wire = protocol._wire
        if wire is not None:  # the common case of _take_one compiled; every other state goes to it in its turn
            n = wire.take_states(states, self.id, ahead, now, mono, self.w_state, self.table, self.rx, self.away,
                                 self._take_one)  # it counts its own: add after the call
            self.states_received += n
            return
        for s, key in states:
            self._take_one(s, key)

    def _take_one(self, s: State, key: str) -> None:
        """Real time (under the lock, within _on_states): one state of the batch, at its clocks (_batch)."""
        now, ahead, mono = self._batch
        j, t = s.id, s.t
        if j == self.id or t > ahead:
            self._on_state(s, key)  # refused, and counted, the long way
            return
        w = self.w_state.get(j)
        if w is None:
            w = self.w_state[j] = window.Window(math.inf, 2**62)  # forward only (see _on_state)
        v = w.check(t, s.seq)
        if v != window.OK and not self.bad.verdict(key, v, f"robot {j}'s t or seq"):
            return
        self.states_received += 1
        self.table[j] = s
        self.rx[j] = (0.0 if now is None or now <= t else now - t, mono)
        self.away.discard(j)

    def _due(self) -> bool:
        if self.pose is None:
            return False
        if not self.cfg.lockstep:
            return self.pose.seq != self._rt_seq  # real time: a new pose, a new command
        if self.pose.seq > self.k_started:
            return True  # a new tick to start
        return self.k_started > self.k_done and self._inputs_complete(self.k_started)

    def _inputs_complete(self, k: int) -> bool:
        if self._idle == k:
            return True  # dead or hung at k (the fault schedule): nothing to compute
        return k in self.refs and self.clock_seq >= min(k, self._clock_needed) and not self.waiting and \
            (self.view is None or k in self.static_by_seq)

    _idle = -1  # lock-step under faults: the tick this robot's process is dead or hung at
    _overdue = 0  # lock-step ticks computed without all their inputs (after wait_timeout)
    _world_ups = 0  # times the world's token appeared
    world_alive = False  # the world's token is there
    _announce = False  # lock-step under faults: its session came back; tell the world (FaultStats)

    _clock_needed = 0  # lock-step: clock_0 is the start barrier; later ticks need no clock message
    _rt_seq = -1  # real time: seq of the pose the last command was computed from

    def _on_clock(self, c: protocol.Clock, key: str = "") -> None:
        if not self.bad.verdict(key, self.w_clock.check(c.t, c.seq), "the clock's t or seq"):
            return
        self.clock_seq = max(self.clock_seq, c.seq)
        if c.epoch > 0 and self.epoch is None:  # real time: the run's epoch, once (a new run is a new agent)
            self.clock.anchor()  # take up a step of the system clock made before this run
            self.epoch, self.speed = c.epoch, c.speed

    def _on_state(self, s: State, key: str = "") -> None:
        """A neighbour's state. A robot hears a neighbour only while they share cells, so the gap between
        two of its states has no bound: its window is on this robot's own clock instead (lock-step: a
        state of a tick at most one ahead of this robot's; real time: t at most t_span ahead of now),
        and per sender only forward (older: stale; the same again: a duplicate)."""
        if s.id == self.id:  # it never hears its own (put with no loopback): another sender with its id
            self.bad.reject(key, ProtocolError(f"a state with this robot's own id {s.id} from elsewhere (an impostor)"))
            return
        if self.cfg.lockstep:
            nxt = self._next_tick()
            if self.view is not None and s.seq > nxt and not self.view.active(nxt):
                return  # its process is away by the fault schedule: states pass it by (no fault of the sender's)
            ahead = s.seq > nxt
        else:
            now = self.sim_time(self.clock.time())
            ahead = now is not None and s.t > now + self._spans[0]
        if ahead:
            self.bad.reject(key, ProtocolError(f"robot {s.id}'s state (t {s.t:g}, seq {s.seq}) is ahead of this "
                                               f"robot's clock beyond the window"))
            return
        w = self.w_state.get(s.id)
        if w is None:
            w = self.w_state[s.id] = window.Window(math.inf, 2**62, dt=self._tick)  # forward only (see above)
        v = w.check(s.t, s.seq)
        if v != window.OK and not self.bad.verdict(key, v, f"robot {s.id}'s t or seq"):
            return
        self.states_received += 1
        self.table[s.id] = s
        if self.cfg.lockstep:
            if s.seq == self.k_started:
                self.waiting.discard(s.id)
        else:  # its age when it came: now on the swarm's clock minus its time (never below 0: clocks differ)
            self.rx[s.id] = (0.0 if now is None else max(0.0, now - s.t), self.clock.monotonic())
            self.away.discard(s.id)

    def _on_alive(self, j: int, up: bool) -> None:
        """Robot j's token came (up) or went (under the lock): a robot that goes is a static body for the law at
        its last state (real time: the safety rule keeps its motion bound until the world lists it: _rt_bodies);
        both are logged."""
        if up:
            if j in self.dead:
                log.info("robot %d: robot %d back (its liveliness token is here again)", self.id, j)
            self.dead.discard(j)
        else:
            if j not in self.dead:  # once the world is gone (the end of a run) robots leaving is no news
                log.log(logging.WARNING if self.world_alive else logging.INFO,
                        "robot %d: robot %d lost (its liveliness token is gone)", self.id, j)
            self.dead.add(j)
            self.waiting.discard(j)

    def _on_ref(self, ref: protocol.Ref, key: str = "") -> None:
        v = self.w_ref.check(ref.t, ref.seq)
        if v == window.JUMP and self.counters is not None and self.w_ref.t is not None:
            lost = getattr(self.counters, "lost_t", (-math.inf,) * 4)[3]  # [faultgen.CLS_REF]
            if self.w_ref.t < lost < ref.t <= lost + self.w_ref.t_span:
                # real time under faults: its fault bus lost the references in between (a partition, a burst of
                # drops), and this one is within the window of the last it lost: the schedule's gap, not the
                # leader's jump (each was counted bad, 2 at a partition's end); a reference farther is refused
                self.w_ref.reset()
                v = self.w_ref.check(ref.t, ref.seq)
        if not self.bad.verdict(key, v, "the reference's t or seq"):
            return
        self.ref = ref
        self.refs_taken += 1
        if self.guard is not None:
            self.guard.ref(ref.t)
        if self.cfg.lockstep and ref.seq > self.k_done:
            self.refs[ref.seq] = ref

    def _next_tick(self) -> int:
        """Lock-step: the newest tick this robot can hear of now: the one after the newest it started or was
        posed (a message of a later tick is ahead of it, refused). Under faults, a robot whose process is away
        by the schedule next runs at its return tick; a new process that may be a restarted one (no pose yet)
        at its last return tick."""
        now = max(self.k_started, self.pose.seq if self.pose is not None else -1)
        view = self.view
        if view is None or view.active(now + 1) and now >= 0:
            return now + 1
        if now < 0:
            return max(0, view.last_return() or 0)
        ret = view.schedule.next_return(self.id, now)
        return now + 1 if ret is None else ret

    def _on_pose(self, pose: protocol.Pose, key: str = "") -> None:
        if self.view is not None and self.view.schedule.fresh(self.id, pose.seq) is not None and \
                pose.seq > max(self.k_started, self.pose.seq if self.pose is not None else -1):
            self.w_pose.reset()  # it returns at pose.seq (restarted or resumed): its poses resume after a gap
        if not self.bad.verdict(key, self.w_pose.check(pose.t, pose.seq), "the pose's t or seq"):
            return
        if not self.cfg.lockstep:
            mono = self.clock.monotonic()
            last = self.pose
            if last is None:
                self._heard_from = mono  # states before its first pose: nothing known of what it missed
            elif pose.seq != last.seq + 1 or mono - self._pose_mono > HEAR_GAP_PERIODS * self._period_wall():
                gaps = self._gaps  # a pose lost or late: states may have been missed in between
                if len(gaps) == gaps.maxlen:
                    self._heard_from = gaps[0][1]
                gaps.append((self._pose_mono, mono))
            self._pose_mono = mono
        self.pose = pose

    _pose_mono = -math.inf  # real time: when the newest pose came (monotonic)
    _heard_from = math.inf  # real time: states that came before this (monotonic) take the speed bound over their age

    def _missed(self, m0: float) -> float:
        """Real time: how long [simulated s] since monotonic time m0 this robot may have missed states (the gaps
        in its poses since); inf when that is not known (before its first pose, or further back than it keeps)."""
        if m0 < self._heard_from:
            return math.inf
        out = 0.0
        for a, b in reversed(self._gaps):
            if b <= m0:
                break
            out += b - (a if a > m0 else m0)
        return out * self.speed

    def _start_tick(self, pose) -> None:
        """Lock-step tick k starts (loop thread): publish state_k, decide whose state_k to wait for.
        Under faults the state is the robot's belief (its pose as it knows it: agents.faultview), and a
        robot whose process the schedule says is dead or hung at k does nothing."""
        k = pose.seq
        view = self.view
        if view is not None:
            b = view.start(k, (pose.x, pose.y, pose.theta))
            if b is None:
                with self.lock:
                    self._idle = k
                    self.waiting = set()
                    self.k_started = k
                self._move_cells(pose.x, pose.y)  # where it stands (raw: for its subscriptions only)
                return
            pose = protocol.Pose(t=pose.t, seq=k, x=b[0], y=b[1], theta=b[2])
            self.belief = pose
        self._move_cells(pose.x, pose.y)
        self._publish_state(pose, k)
        with self.lock:
            if view is not None:
                px, py, _ = view.previous(k)
            else:
                px, py = self.prev_xy if self.prev_xy is not None else (pose.x, pose.y)
            dead = self.dead
            reach2 = self._wait_reach * self._wait_reach
            wire = protocol._wire if view is None else None
            if wire is not None:  # the two loops below, compiled (swarm/proto/_wire.c)
                self.waiting = wire.wait_for(self.table, dead, k, px, py, reach2)
            else:
                self.waiting = set()
                for j in [j for j, nb in self.table.items() if nb.seq < k - 1 and j not in dead]:
                    del self.table[j]  # never used again (bounded state): a live robot counts only with state_k or state_(k-1)
                for j, nb in self.table.items():
                    if nb.seq == k - 1 and j not in dead and (px - nb.x) * (px - nb.x) + (py - nb.y) * (py - nb.y) < \
                            reach2 and (view is None or view.other_active(j, k)):  # under faults: nobody waits for a stopped robot
                        self.waiting.add(j)
            if view is not None and view.event is not None:
                # it returns at k (restarted or resumed): it knows nobody's state of k - 1, so it waits for
                # every robot running at k (heard in every cell: _listen_all), but those already here
                self.waiting = {j for j in range(self.cfg.robots) if j != self.id and j not in dead and
                                view.other_active(j, k) and not (j in self.table and self.table[j].seq == k)}
                if view.event == "restart":
                    # a fresh controller (the same object when the process was not really killed: swarm world
                    # --process-faults played)
                    self.mem = self.control.fresh_memory()
            self.deadline = self.clock.monotonic() + self.wait_timeout
            self._leader_ups_seen = self.leader_ups
            self.k_started = k

    # ------------------------------------------------------------------ control

    def _publish_state(self, pose, seq: int) -> None:
        c = keys.cell_of(pose.x, pose.y, self.side)
        key = self._state_keys.get(c)
        if key is None:
            key = self._state_keys[c] = keys.cell(self.fleet, c[0], c[1], self.id)
        # the fields in State's order, encoded without building one (protocol.encoder)
        s = self._enc_state(self.id, pose.t, seq, pose.x, pose.y, pose.theta, self._r, self._R,
                            bool(self.mem[law.M_FROZEN]), self._rt_stop, self._rt_still)
        self.bus.put(key, s, loopback=False)  # its own state is of no use to this robot's cell inboxes
        if not self.cfg.lockstep:
            self._tell_cells_left(key, pose.t, s)

    def _tell_cells_left(self, key: str, t: float, s: bytes) -> None:
        """Real time: the state s (of time t, put on `key`, its cell's) goes to the cells this robot left within
        DEPART_S too (the first after a change, then every DEPART_EVERY-th), so a robot that heard it there and does not hear its new cell learns where it went (the
        knowledge rule takes a neighbour as away only on such news: _rt_bodies)."""
        left = self._left
        last = self._last_key
        due = key != last  # the first at once, then every DEPART_EVERY-th
        if due:
            if last is not None:
                left[last] = t + DEPART_S
            left.pop(key, None)
            self._last_key = key
            self._since_left = 0
        self._since_left += 1
        if left:
            due = due or self._since_left % DEPART_EVERY == 0
            for k, until in list(left.items()):
                if t > until:
                    del left[k]
                elif due:
                    self.bus.put(k, s, loopback=False)

    _last_key: str | None = None  # real time: the cell key of its last state
    _since_left = 0  # real time: states put since its last cell change

    def bodies(self, x: float, y: float, seq: int):
        """Lock-step: the known bodies closer than the cell side, in summation order: live robots by id, the
        obstacles by index, dead robots by id (static bodies). A live robot counts with its state of this tick,
        or, when it was awaited and did not come, its last one (stale). Returns lists nx, ny, nr, nR, nk, na
        (ages, all 0) and the numbers of robots and stale robots used. Real time: _rt_bodies."""
        r2 = self.side * self.side
        wire = protocol._wire
        if wire is not None:  # the loop below over the table, compiled (swarm/proto/_wire.c)
            nx, ny, nr, nR, nk, na, robots, stale, oldest, dead_near = wire.lock_bodies(
                self.table, self.dead, self.waiting, seq, x, y, r2, law.KIND_ROBOT)
            if dead_near or self.obstacles:
                self._static_bodies(x, y, r2, nx, ny, nr, nR, nk, na, dead_near)
            return nx, ny, nr, nR, nk, na, robots, stale
        nx, ny, nr, nR, nk, na = [], [], [], [], [], []
        robots = stale = 0
        table, dead, waiting = self.table, self.dead, self.waiting
        dead_near = []
        for j in sorted(table):
            nb = table[j]
            if j in dead:
                dead_near.append(nb)
                continue
            if nb.seq != seq and j not in waiting:
                continue
            dx = x - nb.x
            dy = y - nb.y
            if dx * dx + dy * dy < r2:
                nx.append(nb.x)
                ny.append(nb.y)
                nr.append(nb.r)
                nR.append(nb.R)
                nk.append(law.KIND_ROBOT)
                na.append(0.0)
                robots += 1
                stale += nb.seq != seq
        self._static_bodies(x, y, r2, nx, ny, nr, nR, nk, na, dead_near)
        return nx, ny, nr, nR, nk, na, robots, stale

    def _rt_bodies(self, x: float, y: float, t: float, end: float):
        """Real time (under the lock): the law's bodies as in lock-step (robots by id closer than the cell side,
        with their last state however old, then the obstacles near, then the robots standing still: dead ones
        and those the world lists; ages 0: the law and its governor run as in lock-step), and the safety rule's
        bodies (x, y, contact distance, the most the body can be from (x, y) by `end`: swarm.core.safety).

        What a robot knows (docs/runtime.md, "The safety invariant"): every robot with its last state and that
        state's age (the age it had when it came plus the time since, on this robot's clock), never forgotten while
        it may be near: only a robot whose newest state puts it outside this robot's block of cells (the 3x3 it
        hears: everything within the cell side) is taken as away, until a newer state comes (a robot that leaves
        a cell keeps putting its states there a while: DEPART_S), and never one that a partition of the run's
        faults cuts off from this robot now. Not hearing a robot says nothing of where it is: its link may be
        stalled or down. A robot whose token is gone is a static body for the law; the safety rule keeps its
        motion bound (this robot's newest state of it need not be its last) until the world lists it: the robots
        the world lists stand still until the listing's t + BODIES_HOLD_S. Returns the law's lists nx, ny, nr,
        nR, nk, na, the numbers of robots and stale robots it uses, the safety rule's list, and the information
        delay [s] (_info_delay)."""
        side = self.side
        r2 = side * side
        mono = self.clock.monotonic()
        speed, V, eps = self.speed, self.V, safety.CLOCK_SKEW_S
        cx, cy = math.floor(x / side), math.floor(y / side)
        nx, ny, nr, nR, nk, na = [], [], [], [], [], []
        safe = []
        robots = stale = 0
        oldest = 0.0
        news, heard = 0.0, 0  # the ages recent states came with: their mean goes into the information delay
        table, dead, away, rx, beyond = self.table, self.dead, self.away, self.rx, self._beyond
        dead_near = []
        listed = self._listed_now()
        # what a neighbour heard in order may do: its announced stop, and V over the times a command of it this
        # robot has not heard of may have begun: since the newest pose came, and in the gaps of its poses since the
        # state came (each plus the longest reservation); only on links that keep order (no fault bus)
        pose = self.pose
        since_pose = end - t + (t - pose.t if pose is not None and t > pose.t else 0.0) + eps
        ordered = self._ordered and pose is not None
        reserve = safety.VALIDITY_MAX_S + safety.RAMP_S
        for j in sorted(table):
            nb = table[j]
            a0, m0 = rx.get(j, (0.0, mono))
            since = (mono - m0) * speed if mono > m0 else 0.0
            age = a0 + since
            if since < RECENT_S:
                news += a0
                heard += 1
            dx = x - nb.x
            dy = y - nb.y
            d2 = dx * dx + dy * dy
            contact = nb.r if nb.r > self._r else self._r
            gone = j in dead
            if gone and j in listed:  # the world has it where it stands: that, not its last state, is the body
                continue
            if (abs(math.floor(nb.x / side) - cx) > 1 or abs(math.floor(nb.y / side) - cy) > 1) and \
                    not self._cut_off(j, t, age):
                if j not in beyond:  # its newest state is beyond the cells this robot hears: it hears it come back
                    beyond.add(j)
                    self.forgotten += 1
                away.add(j)
                continue
            beyond.discard(j)
            if gone:
                dead_near.append(nb)
            elif since > PROBE_S and j not in self._probes:
                self._want_probe.add(j)  # kept, not heard: where is it? (_update_probes)
            m = V * (end - t + age + eps)  # safety.motion_bound, inline: the speed bound over the state's age,
            if nb.stop is not None and ordered:  # or what it announced, heard in order (above),
                missed = self._missed(m0)
                quiet = nb.stop + V * (since_pose + (missed + reserve if missed > 0.0 else 0.0))
                if quiet < m:
                    m = quiet
            if nb.still is not None and nb.stop is not None:  # or less while a promise to stand holds
                left = nb.still - nb.t
                ends = t - age + (left if left < safety.PROMISE_MAX_S else safety.PROMISE_MAX_S)
                promised = nb.stop + V * (end - ends + eps if end + eps > ends else 0.0)
                if promised < m:
                    m = promised
            safe.append((nb.x, nb.y, contact, m))
            if not gone and d2 < r2:
                nx.append(nb.x)
                ny.append(nb.y)
                nr.append(nb.r)
                nR.append(nb.R)
                nk.append(law.KIND_ROBOT)
                na.append(0.0)
                robots += 1
                stale += age > STALE_AFTER_S
                if age > oldest:
                    oldest = age
        self._static_bodies(x, y, r2, nx, ny, nr, nR, nk, na, dead_near)
        for ox, oy, orr, _oR in self._obstacles_near(keys.cell_of(x, y, self.side)):
            safe.append((ox, oy, orr, 0.0))
        if listed:  # the robots the world lists as standing still: where it has them
            now = self.sim_time(self.clock.time())
            age = 0.0 if now is None else max(0.0, now - self.rt_static_t)
            m = V * max(0.0, end - t + age - safety.BODIES_HOLD_S + eps)
            for sx, sy, sr, _sR in listed.values():
                safe.append((sx, sy, sr if sr > self._r else self._r, m))
        self.oldest_state_s = oldest
        # nobody heard lately: its own poses' lag says how late a robot coming near would be heard (an old figure
        # kept forever would slow a robot alone for good)
        self._news.add(news / heard if heard else self._lag.value)
        return nx, ny, nr, nR, nk, na, robots, stale, safe, self._info_delay()

    def _listed_now(self) -> dict:
        """Real time: the robots the world lists as standing still (id -> (x, y, r, R)); a list older than
        RT_BODIES_TTL_S is dropped (the world sends one every period while it lists a robot)."""
        if self.rt_static:
            now = self.sim_time(self.clock.time())
            if now is not None and now - self.rt_static_t > RT_BODIES_TTL_S:
                self.rt_static = {}
        return self.rt_static

    def _info_delay(self) -> float:
        """Real time: how old this robot's news may be [s]: a high but typical lag of its poses or age of its
        neighbours' states when they come (the 75th percentile of the recent ones: a robot that comes near is heard
        at its first state that gets through, not its latest), plus GAP_PERIODS periods of losses."""
        return max(self._lag.value, self._news.value) + GAP_PERIODS * self.cfg.dt

    def _cut_off(self, j: int, t: float, span: float) -> bool:
        """Real time under faults: a partition of the run separates this robot from robot j at some time in
        [t - span, t] (their states do not cross: not hearing j says nothing of where it is)."""
        for p in self.partitions:
            if p.start <= t and p.end >= t - span and p.group(self.id) != p.group(j):
                return True
        return False

    def _static_bodies(self, x: float, y: float, r2: float, nx: list, ny: list, nr: list, nR: list, nk: list,
                       na: list, dead_near: list) -> None:
        """bodies(), its static part: the obstacles near, by index, then the dead robots near, by id, then (real time)
        the robots the world lists as standing still, appended (ages 0)."""
        for ox, oy, orr, oR in self._obstacles_near(keys.cell_of(x, y, self.side)):
            dx = x - ox
            dy = y - oy
            if dx * dx + dy * dy < r2:
                nx.append(ox)
                ny.append(oy)
                nr.append(orr)
                nR.append(oR)
                nk.append(law.KIND_OBSTACLE)
                na.append(0.0)
        for nb in dead_near:
            dx = x - nb.x
            dy = y - nb.y
            if dx * dx + dy * dy < r2:
                nx.append(nb.x)
                ny.append(nb.y)
                nr.append(nb.r)
                nR.append(nb.R)
                nk.append(law.KIND_DEAD)
                na.append(0.0)
        if self.rt_static and not self.cfg.lockstep:
            for sx, sy, sr, sR in self._listed_now().values():
                dx = x - sx
                dy = y - sy
                if dx * dx + dy * dy < r2:
                    nx.append(sx)
                    ny.append(sy)
                    nr.append(sr)
                    nR.append(sR)
                    nk.append(law.KIND_DEAD)
                    na.append(0.0)

    def command(self, t: float, x: float, y: float, th: float, ref: tuple, seq: int) -> tuple[float, float]:
        """Lock-step: the law for this robot at time t with pose (x, y, th) and live reference ref = (xl, yl, thl,
        vl, wl), over the bodies of tick seq (the world applies a command for exactly dt: the governor's horizon
        is the period)."""
        nx, ny, nr, nR, nk, na, robots, stale = self.bodies(x, y, seq)
        xl, yl, thl, vl, wl = ref
        v, w = self._law(x, y, th, self.cfg.dx, self.cfg.dy, self.cfg.r, t, xl, yl, thl, vl, wl,
                                     nx, ny, nr, nR, nk, na, len(nx), self.mem, self.p)
        self.neighbours, self.stale = robots, stale
        self.stale_total += stale
        return v, w

    def command_realtime(self, t: float, x: float, y: float, th: float, ref: tuple, pose_t: float,
                         listen: bool = False) -> tuple[float, float]:
        """Real time (under the lock): the command at time t from the pose (x, y, th) of time pose_t, and what its
        state and command announce (_rt_until, _rt_stop, _rt_still). The law runs as in lock-step (its governor's
        horizon the period, every age 0); then, with the governor on, the safety rule (swarm.core.safety;
        docs/runtime.md, "The safety invariant"): the command is valid until t plus two periods and twice the
        recent lag of its poses; the speed stays within the bound V; it is slowed (v and w together: the same
        path) to the largest speed at which everything it can reach from its pose stays clear of everywhere every
        known body (and every robot it has not heard) can be until its motion surely ends, unless it moves away
        from that body; when no speed is allowed it stands (turning in place) and promises to stand a while
        (`still`), so its neighbours may take it as a static body and pass. listen: it holds still (its first
        periods), and says so."""
        dt = self.cfg.dt
        lag = t - pose_t if t > pose_t else 0.0
        self._lag.add(lag)
        until = t + safety.validity(dt, self._lag.value, self._act.value)
        self._sent_at.append((pose_t, t))
        # should this process die, a base with its own timeout acts on the command that long: its reach counts it
        reserve = until if self.base_timeout is None else max(until, t + self.base_timeout)
        eps, ramp = safety.CLOCK_SKEW_S, self.ramp
        vp = wp = 0.0
        ep = -math.inf
        pend = self._pending
        while pend and pend[0][2] + eps + ramp / 2.0 <= pose_t:
            pend.popleft()  # its motion is over by the pose's time
        for a, b, u in pend:
            if a > vp:
                vp = a
            if b > wp:
                wp = b
            if u > ep:
                ep = u
        ep = max(ep + eps + ramp / 2.0, pose_t)  # (-inf without one: the pose's time)
        plan = safety.Plan(pose_t, t, reserve, vp, ep, wp, ramp, self.switch, eps)
        nx, ny, nr, nR, nk, na, robots, stale, safe, delay = self._rt_bodies(x, y, t, plan.end)
        self.neighbours, self.stale = robots, stale
        self.stale_total += stale
        self.max_age = max(self.max_age, self.oldest_state_s)
        if listen:
            v = w = 0.0
        else:
            xl, yl, thl, vl, wl = ref
            self.p[law.P_DT] = dt
            v, w = self._law(x, y, th, self.cfg.dx, self.cfg.dy, self.cfg.r, t, xl, yl, thl, vl, wl,
                                         nx, ny, nr, nR, nk, na, len(nx), self.mem, self.p)
            self.commanded += 1
            if self.cfg.governor and v == v and w == w:  # a NaN goes on to be refused, never driven
                v, w = self._safe(t, x, y, th, v, w, plan, safe, delay)
        self._rt_until = until
        self._rt_stop = plan.reach(abs(v))
        self._rt_still = self._still_until if self._still_until > t else 0.0
        pend.append((abs(v), abs(w), reserve))
        return v, w

    def _safe(self, t: float, x: float, y: float, th: float, v: float, w: float, plan, safe, delay: float
              ) -> tuple[float, float]:
        """Real time: the law's (v, w) within the speed bound and the safety rule (command_realtime)."""
        V, held = self.V, False
        if abs(v) > V:
            f = V / abs(v)
            v, w = v * f, w * f
        if t < self._still_until:  # its promise: it stands (turning in place)
            v, held = 0.0, True
        else:
            sv = 1.0 if v >= 0.0 else -1.0
            unknown = safety.unheard_speed(self.side, self._r, delay, plan.end - t)
            limit, why = plan.limit(x, y, sv * math.cos(th), sv * math.sin(th), w, safe, V, unknown)
            if abs(v) > limit:
                held = True
                self.held_why[why] += 1
                if limit < STAND_BELOW:  # no motion it could make: stand, turn in place, and say it stands a while
                    if log.isEnabledFor(logging.DEBUG):
                        near = sorted((round(math.hypot(x - b[0], y - b[1]) - b[2] - b[3], 3), b[:2]) for b in safe)[:3]
                        log.debug("robot %d stands at t = %.2f s (its law asked v %.3f m/s): held by %s; the nearest "
                                  "bodies' room (m) and places: %s", self.id, t, v,
                                  ("a body", "only moving away from one", "robots it has not heard")[why - 1], near)
                    v = 0.0
                    self._promises += 1
                    jitter = 0.5 * ((math.sin(self.id * 12.9898 + self._promises * 78.233) * 43758.5453) % 1.0)
                    self._still_until = t + min(plan.end - t, safety.PROMISE_S) * (1.0 + jitter)
                else:
                    f = limit / abs(v)
                    v, w = v * f, w * f
        self.held += held
        return v, w

    def _publish(self, t: float, seq: int, v: float, w: float, ref: tuple, pose) -> None:
        if self.estopped is not None:
            v = w = 0.0  # the emergency stop holds every robot still
        until = None if self.cfg.lockstep else self._rt_until  # real time: how long the drive may execute it
        cmd = Cmd(t=t, seq=seq, v=v, w=w, until=until)
        if self.drive is None:  # lock-step: the world's key
            self.bus.put(self._cmd_key, protocol.encode(cmd), reliable=True)
        elif self.guard is not None and self.guard.check(t, until) is not None:
            cmd = Cmd(t=t, seq=seq, v=0.0, w=0.0, until=until)  # halted (the guard says why, once)
            self.drive.hold(t)  # zero, at this period's time: the world's window on its commands moves on with it
        else:
            self.drive.send(cmd)
        self.last_cmd = cmd
        self.ticks += 1
        if t - self._last_status_t >= STATUS_PERIOD_S * (1 - 1e-9):
            self._last_status_t = t
            xl, yl, thl = ref[0], ref[1], ref[2]
            st = Status(t=t, ex=xl + self.cfg.dx - pose.x, ey=yl + self.cfg.dy - pose.y,
                        etheta=law.wrap_angle(thl - pose.theta), frozen=bool(self.mem[law.M_FROZEN]),
                        neighbours=self.neighbours, stale=self.stale, bad=self.bad.count,
                        held=None if self.cfg.lockstep else self.held / max(1, self.commanded))
            self.bus.put(self._status_key, protocol.encode(st))
            if self.counters is not None:
                self._report(t)

    def _report(self, t: float) -> None:
        """Real time under faults: this process's fault counters so far (its bus's), with every status, and
        from the waker while the robot makes no step (report_idle); seq counts the reports of this process
        from 0 (the world keeps the newest of each process)."""
        with self._report_lock:  # the step's thread and the waker's: one seq each, in order
            d, y = self.counters.dropped, self.counters.delayed  # by class: state 0, pose 1, cmd 2, ref 3
            c = protocol.FaultStats(t, self.reports, d[0], d[1], d[3], y[0], y[1], y[3], round(self.max_age, 9),
                                    frozen=bool(self.mem[law.M_FROZEN]))
            self.reports += 1
            self._reported_at = self.clock.monotonic()
            self.bus.put(self._faults_key, protocol.encode(c), reliable=True)

    def report_idle(self) -> None:
        """Real time under faults (the waker's thread): the fault counters, when no status took them for two
        status periods: a robot that makes no step (every pose dropped, say) still says what it lost, so the
        run's metrics count it (docs/faults.md)."""
        if self.counters is None or self.epoch is None or self.ended:
            return
        mono = self.clock.monotonic()
        if mono - self._reported_at < 2 * STATUS_PERIOD_S / max(1e-9, self.speed):
            return
        t = self.sim_time(self.clock.time())
        if t is not None:
            self._report(t)

    def _on_drive_poses(self, poses) -> None:
        """Real time inline (the drive's callback, on the bus's thread): poses, then the step they make due."""
        self._rt_poses.extend(poses)
        self.kick.set()

    def _step_inline(self) -> None:
        """Real time inline (Runner): the poses handed over, then the step (step_realtime)."""
        q = self._rt_poses
        got = []
        while q:
            got.append(q.popleft())
        self.step_realtime(got)

    def step_realtime(self, poses) -> None:
        """Real time: take the poses that came, then a command if a new pose came (or a step without one is
        due: late_due()), at the swarm's clock now."""
        self.take_poses(poses)
        with self.lock:
            epoch, speed, fresh = self.epoch, self.speed, self._due()
        if epoch is None:
            return
        self.drop_clock()  # the epoch is all a real-time robot needs of the clock (one message a period less)
        if fresh:
            self.tick_realtime((self.clock.time() - epoch) * speed)
        else:
            due = self.late_due()
            if due is not None and self.clock.monotonic() >= due:
                self.tick_realtime((self.clock.time() - epoch) * speed, late=True)

    def _ticks(self) -> None:
        """Inline (Runner): every tick that is due now (tick_lockstep until it has nothing to do)."""
        while self.tick_lockstep():
            pass

    def tick_lockstep(self) -> bool:
        """Loop thread: start a new tick if its pose came, and compute it once its inputs are complete
        (or overdue). True if a command (or a skip) was issued."""
        if self._announce:
            self._announce = False
            if self.view is not None:
                # a process stopped before its first tick (hung at tick 0, or at the tick it was restarted for)
                # says so with tick 0 and its counters, all zero then (the world takes that as its word only)
                done = max(self.k_done, 0)
                # its next tick is its return: it hears every cell for it (stopped before its first tick, at 0 or
                # at the tick it was restarted for, it never reached the idle tick that subscribes it)
                with self.lock:
                    nxt = self._next_tick()
                self._listen_all(self.view.schedule.fresh(self.id, nxt) is not None)
                self._resubscribe()
                self.bus.put(self._faults_key, protocol.encode(protocol.FaultStats(
                    done * self.cfg.dt, done, *self.view.counters(),
                    frozen=bool(self.mem[law.M_FROZEN]))), reliable=True)
        with self.lock:
            pose = self.pose
        if pose is None or pose.seq <= self.k_done:
            return False
        if pose.seq > self.k_started:
            self._start_tick(pose)
            if pose.seq > 0 and self.clock_seq >= 0:
                self.drop_clock()  # past the start barrier: the clock is not needed any more
        with self.lock:
            k = self.k_started
            newest: protocol.Pose = self.pose  # type: ignore[assignment]  # not None: a pose came (above)
            pose = newest if newest.seq == k else pose
            overdue = self.clock.monotonic() >= self.deadline
            if overdue and k not in self.refs and (not self.leader_alive or self.leader_ups != self._leader_ups_seen):
                # no reference because the leader is away, or came back during the tick and is catching up:
                # wait for it (the world holds the tick and ends the run if it does not come back)
                self._leader_ups_seen = self.leader_ups
                self.deadline = self.clock.monotonic() + self.wait_timeout
                return False
            if not self._inputs_complete(k) and not overdue:
                return False
            if overdue and not self._inputs_complete(k):
                self._overdue += 1
                if self._overdue <= 5 or self._overdue % 100 == 0:
                    what = ([f"the states of robots {sorted(self.waiting)[:8]}"] if self.waiting else []) + \
                        (["the reference"] if k not in self.refs else []) + \
                        (["the clock"] if self.clock_seq < min(k, self._clock_needed) else []) + \
                        (["the static bodies"] if self.view is not None and k not in self.static_by_seq else [])
                    log.warning("robot %d: tick %d goes on after %g s without %s (%d ticks so far)", self.id, k,
                                self.wait_timeout, ", ".join(what), self._overdue)
            ref = self.refs.get(k)
            self.k_done = k
            self.prev_xy = (pose.x, pose.y)
            for old in [s for s in self.refs if s <= k]:
                del self.refs[old]
            if self.static_by_seq:  # under faults only
                for old in [s for s in self.static_by_seq if s < k]:
                    del self.static_by_seq[old]
            if self.view is not None:
                if self._idle != k:
                    v, w, r = self._command_under_faults(k, ref)
                    belief: protocol.Pose = self.belief  # type: ignore[assignment]  # _start_tick set it: k is not idle
                    pose = belief
            elif ref is None:
                self.skipped += 1  # no reference for this tick (a restart mid-run): no command, the world holds
                log.warning("robot %d: no reference for tick %d, no command", self.id, k)
                return True
            else:
                r = (ref.x, ref.y, ref.theta, ref.v, ref.w)
                v, w = self.command(pose.t, pose.x, pose.y, pose.theta, r, k)
        if self.view is not None:
            # before its command goes out (the world starts the next tick only once it has it): the next
            # tick this robot runs is a return tick, so it hears every cell from now on
            self._listen_all(self.view.returns_next(k))
            if self._idle == k:
                return True  # dead or hung at k: no state, no command (the world knows the schedule)
            c = self.view.counters()
            self.bus.put(self._faults_key, protocol.encode(protocol.FaultStats(
                pose.t, k, *c, frozen=bool(self.mem[law.M_FROZEN]))), reliable=True)
        self._publish(pose.t, k, v, w, r, pose)
        return True

    def _command_under_faults(self, k: int, ref) -> tuple[float, float, tuple]:
        """Lock-step under faults (under the lock): the law given what the fault layer delivered; returns
        (v, w, the reference the law used, or the raw one for the status)."""
        view: FaultView = self.view  # type: ignore[assignment]  # tick_lockstep calls this under faults only
        view.reference(k, None if ref is None else (ref.x, ref.y, ref.theta, ref.v, ref.w))
        fresh = {j: (nb.x, nb.y) for j, nb in self.table.items() if nb.seq == k}
        for j in sorted(set(fresh) | set(view.tk) | set(view.ring_state)):
            if j != self.id:
                view.neighbour(k, j, fresh.get(j))
        listen, r = view.law_inputs(k)
        b: protocol.Pose = self.belief  # type: ignore[assignment]  # _start_tick set it: tick k is not idle
        if listen or r is None:
            v = w = 0.0  # listening (just restarted or resumed), or no reference yet: it holds still
            r = r or (b.x - self.cfg.dx, b.y - self.cfg.dy, b.theta, 0.0, 0.0)
        else:
            static = self.static_by_seq.get(k, {})
            nx, ny, nr, nR, nk, na = view.bodies(k, static, self.obstacles, self.cfg.r, self.cfg.R, law.KIND_ROBOT,
                                                 law.KIND_OBSTACLE, law.KIND_DEAD)
            xl, yl, thl, vl, wl = r
            v, w = self._law(b.x, b.y, b.theta, self.cfg.dx, self.cfg.dy, self.cfg.r, k * self.cfg.dt, xl, yl,
                                         thl, vl, wl, nx, ny, nr, nR, nk, na, len(nx), self.mem, self.p)
            self.neighbours = sum(1 for kind in nk if kind == law.KIND_ROBOT)
        view.commanded(k, v, w)
        return v, w, r

    def next_wakeup(self) -> float:
        """Seconds until tick_lockstep() may act by timeout (a bound for the loop's wait)."""
        with self.lock:
            if self.pose is None or self.pose.seq <= self.k_done:
                return 0.5
            if self.pose.seq > self.k_started:
                return 0.0
            return max(0.0, self.deadline - self.clock.monotonic())

    def sim_time(self, wall: float) -> float | None:
        """Real time: the simulated time at unix time `wall` (None before the world's clock is known)."""
        if self.epoch is None:
            return None
        return (wall - self.epoch) * self.speed

    def tick_realtime(self, t: float, late: bool = False) -> bool:
        """Real time: one control step at simulated time t with the newest data. True if it acted.
        late: no new pose came in time (late_due()): its pose is taken as lost, and the step starts from
        the pose it last commanded from, advanced by its own last command to t (docs/faults.md)."""
        self._take_inboxes()
        with self.lock:
            pose, ref = self.pose, self.ref
        if pose is None or ref is None:
            return False
        last = self.last_cmd
        moved = True  # the pose it computes from is not the one it was given
        if late:
            if self._rt_belief is None or last is None:
                return False
            bt, bx, by, bth = self._rt_belief
            pose_t, x, y, th = self._advanced(bt, bx, by, bth, last, t)
            self.reckoned += 1
            self._late_next += self._period_wall()
            if self.late_timer is not None:
                self.late_timer.arm(self._late_next)
        else:
            self._rt_seq = pose.seq
            pose_t, x, y, th = pose.t, pose.x, pose.y, pose.theta
            if pose.cmd is not None and pose.cmd >= 0.0:
                self._acting(pose.t, pose.cmd)
            if pose_t < self._rt_t and last is not None:
                # older than what it last published (a late pose after a step without one): brought to
                # that time by its own last command, so its state and command never go back in time
                pose_t, x, y, th = self._advanced(pose_t, x, y, th, last, self._rt_t)
            else:
                moved = False
        self._move_cells(x, y)
        self.seq += 1
        # the reference advanced exactly along the leader's arc to now (its v, w are constant between messages)
        dx, dy, dth = kinematics.arc_displacement(ref.theta, ref.v, ref.w, t - ref.t)
        r = (ref.x + dx, ref.y + dy, ref.theta + dth, ref.v, ref.w)
        if self._first_pose_t is None:
            self._first_pose_t = pose_t
        # just started: listen before moving (the neighbours' first states are still on their way; a command
        # computed without them would be blind to a robot 0.5 m away): hold still, say so
        listen = pose_t - self._first_pose_t < LISTEN_PERIODS * self.cfg.dt - 1e-9
        with self.lock:
            v, w = self.command_realtime(t, x, y, th, r, pose_t, listen)
        # the law clips its speed bound's rounding; the governor's scaling can add one more ulp: a command one
        # ulp beyond the bound would be refused, and the world would hold the previous one (seen once near an
        # obstacle, at 100 rad/s). A NaN stays a NaN (the codec refuses it)
        v, w = law.clip(v, self._vb), law.clip(w, self._wb)
        # state and command go out back to back, so zenoh sends them in one write (one wake-up of its
        # thread instead of two); the command is stamped with its pose's time: a drive (or the world)
        # sees how old its input is
        used = protocol.Pose(t=pose_t, seq=pose.seq, x=x, y=y, theta=th) if moved else pose
        self._publish_state(used, self.seq)
        self._publish(pose_t, self.seq, v, w, r, used)
        self._rt_t = pose_t
        self._rt_belief = (pose_t, x, y, th)
        if self._want_probe or self._probes:
            self._update_probes()  # after the command is out: subscriptions cost a declaration each
        return True

    def _acting(self, t: float, cmd_t: float) -> None:
        """Real time: at time t its drive executes the command that carried cmd_t (a pose's `cmd`): how long that
        one took from its computation to here goes into the recent ones (the commands' validity follows them)."""
        sent = self._sent_at
        while sent and sent[0][0] < cmd_t:
            sent.popleft()  # older than the one acting: never looked up again
        if sent and sent[0][0] == cmd_t:
            self._act.add(t - sent[0][1])

    @staticmethod
    def _advanced(t0: float, x: float, y: float, th: float, cmd: Cmd, t: float) -> tuple[float, float, float, float]:
        """(t, x, y, theta): the pose (x, y, th) of time t0 moved along its command's exact arc to t."""
        dx, dy, dth = kinematics.arc_displacement(th, cmd.v, cmd.w, max(0.0, t - t0))
        return max(t, t0), x + dx, y + dy, th + dth

    def _period_wall(self) -> float:
        """Real time: the control period in wall seconds."""
        return self.cfg.dt / max(1e-9, self.speed)

    def pose_taken(self, mono: float) -> None:
        """Real time (the step's thread): a new pose was taken at monotonic time mono: the next one is due a period
        on (late_timer armed with it)."""
        self.last_pose_at = mono
        self._late_next = mono + POSE_LATE_PERIODS * self._period_wall()
        if self.late_timer is not None:
            self.late_timer.arm(self._late_next)

    _late_next = math.inf  # real time: when a step without a pose is due (monotonic), if none comes before
    periodic = False  # real time: its drive's poses come once a control period (a missing one is lost)

    def late_due(self) -> float | None:
        """Real time: the monotonic time at which a step without a new pose is due (None: none is; only with
        a periodic drive, and for WATCHDOG_S after the last pose: then the guard halts the drive anyway)."""
        if not self.periodic or self.last_pose_at is None or self.epoch is None or self._rt_belief is None:
            return None
        due = self._late_next
        return due if due - self.last_pose_at <= WATCHDOG_S else None


# ---------------------------------------------------------------------- process level


def fetch_config(bus, fleet: str, robot_id: int, timeout_s: float, stop: threading.Event | None = None,
                 run: str | None = None) -> Config:
    """Ask the world's configuration queryable for this robot's slice (of run `run`, if given),
    retrying until timeout_s (NoAnswer)."""
    key = keys.world_config(fleet, robot_id)
    return query_until(bus, key, "config", robot_id, timeout_s, stop, what=f"the configuration of robot {robot_id}",
                       accept=None if run is None else (lambda c: c.run == run))


def fetch_obstacles(bus, fleet: str, timeout_s: float, stop: threading.Event | None = None) -> list[protocol.Obstacle]:
    msg = query_until(bus, keys.world_obstacles(fleet), "obstacles", None, timeout_s, stop, what="the obstacles")
    return list(msg.obstacles)


def within_limits(cfg: Config, limits: tuple[float, float] | None) -> Config:
    """The configuration with v_max and w_max tightened to a drive's own (its robot model's) limits: the law, its
    governor and the command clip then keep to them. No limits (None): cfg as it is; a limit of cfg's 0 is none."""
    if limits is None:
        return cfg
    from dataclasses import replace

    v, w = limits
    return replace(cfg, v_max=v if cfg.v_max <= 0 else min(cfg.v_max, v),
                   w_max=w if cfg.w_max <= 0 else min(cfg.w_max, w))


def run_robot(bus, clock, robot_id: int, fleet: str = "default", stop: threading.Event | None = None,
              scenario=None, start_timeout: float = 60.0, wait_timeout: float = WAIT_TIMEOUT_S,
              once: bool = False, make_drive=None, ref_timeout: float = REF_TIMEOUT_S,
              pose_timeout: float = WATCHDOG_S, mode: str | None = None, law_file: str | None = None) -> list[Agent]:
    """Serve runs as robot `robot_id` on `bus` until `stop` is set: for every run the world announces,
    a fresh agent (tick state, windows, controller) with this robot's slice of the run's scenario:
    from `scenario` (this process's own; a run of another scenario is refused: RunRefused) or from
    the world's configuration queryable. NoAnswer if no world answers within start_timeout. Returns
    the agents of the runs served (their counters). clock: swarm.core.clock (WALL in a process).
    once: serve one run only. Real time: make_drive(cfg, now) builds the drive (swarm.drives; default
    the simulated world's keys; now() is the swarm's clock) and a guard (agents.guard) halts it when
    its pose is older than pose_timeout, the reference is extrapolated longer than ref_timeout, the
    leader is lost or the emergency stop is engaged. mode ("lockstep" or "realtime", swarm robot --mode): a
    run of the other mode is refused (RunRefused); None takes the world's. law_file: this machine's copy of the
    run's law, when not where the run's config says (agents.control)."""
    stop = stop or threading.Event()
    current: list[Agent] = []

    def on_new(run) -> None:  # on the bus's thread: the agent of the run under way ends (its loop returns)
        for a in list(current):
            a.end()

    runs = RunFollower(bus, fleet, on_new)
    mine = runid.canonical(scenario) if scenario is not None else None
    served: list[Agent] = []
    # who this process is (`swarm ps`), from the start: a robot waiting for a run has no token yet
    proc = presence.serve(bus, fleet, "robot", robot_id, run=lambda: current[0].cfg.run if current else "")
    try:
        run = runs.current(start_timeout, stop, me=("robot", robot_id))
        while not stop.is_set():
            if mine is not None and not run.scenario:
                run = runs.complete(run, start_timeout, stop)  # to name the first difference, if any
            check_run(run, mine, robot_id, mode)
            faults = None
            if scenario is not None:
                cfg = runid.robot_config(scenario, robot_id, run.lockstep, run.run, run.digest)
                faults = scenario.faults
            else:
                cfg = fetch_config(bus, fleet, robot_id, start_timeout, stop, run=run.run)
                # under faults every process reads the same schedule (the run's)
                run = runs.complete(run, start_timeout, stop)
                faults = _run_faults(run)
            obstacles = fetch_obstacles(bus, fleet, start_timeout, stop)
            drive = guard = fbus = None
            rbus = bus
            box: list[Agent] = []
            if cfg.lockstep and make_drive is not None:
                make_drive(cfg, lambda: None)  # raises DriveRefused: a real drive has no ticks
            if not cfg.lockstep:
                if faults:  # real time under faults: what this robot receives goes through the fault model
                    rbus = fbus = _fault_bus(bus, faults, cfg, fleet, clock, box)
                now = (lambda: box[0].sim_time(clock.time()) if box else None)
                drive = make_drive(cfg, now) if make_drive is not None else None
                cfg = within_limits(cfg, drive.speed_limits if drive is not None else None)
                if drive is None:
                    from swarm.drives.sim import SimDrive

                    drive = SimDrive(rbus, fleet, robot_id)
                guard = Guard(drive, clock, pose_timeout_s=pose_timeout, ref_timeout_s=ref_timeout, arena=arena_of(cfg),
                              expire=not drive.enforces_validity)
            agent = Agent(rbus, cfg, fleet, wait_timeout=wait_timeout, clock=clock, drive=drive, guard=guard,
                          faults=faults if cfg.lockstep else None, counters=fbus,
                          inline=getattr(rbus, "threaded_callbacks", False),
                          partitions=() if cfg.lockstep or not faults else faults.partitions, law_file=law_file)
            box.append(agent)
            current[:] = [agent]
            if runs.latest is not None and runs.latest.run != run.run:
                agent.end()  # another run began while this one was being set up
            log.info("robot %d: run %s (%s, %d robots; law %s, wire codec %s)", robot_id, run.run,
                     "lock-step" if run.lockstep else "real time", run.robots, agent.control.label,
                     "compiled" if protocol._wire is not None else "Python")
            try:
                agent.start(obstacles)
                settle_heap()
                if guard is not None:
                    guard.start(lambda: agent.sim_time(clock.time()), lambda: agent.speed)
                p0 = time.process_time()
                if cfg.lockstep:
                    _loop_lockstep(agent, stop)
                else:
                    _loop_realtime(agent, stop)
                agent.process_cpu_s = time.process_time() - p0  # read by the log line below, reached only from here
                if not cfg.lockstep:
                    said_step(clock, log, f"robot {robot_id}", run.run)
            finally:
                if guard is not None:
                    guard.close()
                agent.close()  # halts and closes the drive: on every way out
                if fbus is not None:
                    fbus.detach()
                current.clear()
            log.info("robot %d, run %s: %d ticks, %d skipped, %d states and %d references received, %d bad messages, "
                     "%d stale, %d duplicated, loop CPU %.0f us a tick, process CPU %.0f us a tick", robot_id,
                     agent.cfg.run, agent.ticks, agent.skipped, agent.states_received, agent.refs_taken, agent.bad.count,
                     agent.bad.stale, agent.bad.duplicates, 1e6 * agent.loop_cpu_s / max(1, agent.ticks),
                     1e6 * agent.process_cpu_s / max(1, agent.ticks))
            if not agent.cfg.lockstep:
                w = agent.held_why
                log.info("robot %d, run %s: safety rule: %d of %d commands held back (by a body %d, only away from "
                         "one %d, robots unheard %d, its promise %d), %d promises to stand, %d neighbours taken as "
                         "away, %d listened for in every cell", robot_id, agent.cfg.run, agent.held, agent.commanded,
                         w[safety.BODY], w[safety.AWAY_ONLY], w[safety.UNKNOWN], agent.held - sum(w),
                         agent._promises, agent.forgotten, agent.probed)
            served.append(agent)
            if once:
                break
            nxt = runs.next(after=run.run, stop=stop)
            if nxt is None:
                break
            run = nxt
    finally:
        runs.close()
        proc.close()
    return served


def _fault_bus(bus, faults, cfg: Config, fleet: str, clock, box: list):
    """Real time under faults: a swarm.net.faultbus.FaultBus around bus for this robot. Its holds follow the
    swarm's speed, which the agent (box[0], once made) learns from the clock."""
    from swarm.core.faulttable import FaultTable
    from swarm.net.faultbus import FaultBus

    table = FaultTable.of(faults, cfg.robots, cfg.dt)
    return FaultBus(bus, table, cfg.id, cfg.dt, fleet, speed=lambda: box[0].speed if box else 1.0, clock=clock)


def _run_faults(run):
    """The faults of a run (its scenario text), or RunRefused naming why they do not check."""
    from agents.follow import RunRefused
    from swarm.core.errors import ScenarioError

    try:
        return runid.faults_of(run.scenario, run.robots, f"run {run.run}")
    except ScenarioError as e:
        raise RunRefused(f"run {run.run}'s faults do not check: {e}") from None


def _loop_lockstep(agent: Agent, stop: threading.Event) -> None:
    """Lock-step: the ticks as they become due. Inline (agent.kick a Runner), the bus's threads run them and
    this thread wakes only to close what they released, and for a tick overdue (its deadline); a tick run
    on another thread while this one looks (next_wakeup() then says 0) is waited for in short naps."""
    cpu = time.thread_time
    runner = agent.kick if isinstance(agent.kick, Runner) else None
    least = 0.0 if runner is None else 0.002
    try:
        while not stop.is_set() and not agent.ended:
            agent.wake.wait(min(0.2, max(least, agent.next_wakeup())))
            c0 = cpu()
            agent.wake.clear()
            if runner is None:
                while agent.tick_lockstep():  # a tick done; the next pose may already be here
                    pass
            else:
                agent.close_released()
                runner.set()  # a tick overdue (or one due that no bus thread runs now)
                if runner.error is not None:
                    raise runner.error
            agent.loop_cpu_s += cpu() - c0
    finally:
        if runner is not None:
            agent.loop_cpu_s += runner.cpu_s  # the ticks' CPU, wherever they ran


def _loop_realtime(agent: Agent, stop: threading.Event) -> None:
    """Real time: a command for every new pose (the pose stream sets the control rate: the world's
    control period now, localization's rate on a real robot), at the agent's own clock's time.
    No new pose, no command, and the drive's watchdog stops the robot; but with a periodic drive (the
    simulated world's) a pose that has not come POSE_LATE_PERIODS periods after the last one is taken
    as lost, and the step goes on from the last pose advanced by its own command (Agent.late_due).
    The loop blocks on its drive's pose inbox: zenoh's receiving thread runs no Python and hands the
    pose straight to this thread (no callback, no GIL hand-over, no event). A helper thread wakes it on
    stop, and when a step without a pose is due. Inline (agent.kick a Runner: the simulated drive on
    zenoh, no faults), the drive's pose callback runs the step on zenoh's thread and the helper runs a step
    without a pose; this thread only closes what the steps let go, and returns on stop."""
    done = threading.Event()
    runner = agent.kick if isinstance(agent.kick, Runner) else None
    waker = threading.Thread(target=_watch, args=(stop, done, agent.drive if runner is None else _Kick(agent), agent),
                             daemon=True, name=f"robot-{agent.id}-waker")
    waker.start()
    cpu = time.thread_time
    try:
        while not stop.is_set() and not agent.ended:
            if runner is None:
                got = cast("Drive", agent.drive).wait()
                c0 = cpu()
                agent.step_realtime(got)
            else:  # the steps run on the drive's callback (and the waker's thread): wake for stop and closing
                agent.wake.wait(0.2)
                c0 = cpu()
                agent.wake.clear()
                agent.close_released()
                if runner.error is not None:
                    raise runner.error
            agent.loop_cpu_s += cpu() - c0
    finally:
        done.set()
        if agent.late_timer is not None:
            agent.late_timer.stop()  # the waker's wait returns now
        waker.join(1.0)
        if runner is not None:
            agent.loop_cpu_s += runner.cpu_s  # the steps' CPU, wherever they ran


def _watch(stop: threading.Event, done: threading.Event, box, agent: Agent) -> None:
    """The real-time loop's helper: wake it (box.wake()) on stop, and when a step without a pose is due."""
    name_thread("waker")
    woke_for = None
    timer = agent.late_timer
    while not done.is_set():
        try:
            agent.report_idle()
        except Exception as e:  # the session is closing: the run is over anyway
            log.debug("robot %d: no idle fault report: %s", agent.id, e)
        due = agent.late_due()
        if due is None:
            left = 0.2
        elif due == woke_for:  # the loop has not taken that one yet: look again in half a period
            left = min(0.2, agent._period_wall() / 2)
        else:
            left = min(0.2, max(0.0, due - agent.clock.monotonic()))
        if timer is not None:
            # the agent arms the timer with each new due (every pose moves it a period on): the wake-ups that
            # find it moved stay in C, without the GIL; stop is seen within 0.2 s
            if due is None or due == woke_for:
                time.sleep(left)
            else:
                timer.wait(0.2)
            if stop.is_set() or agent.ended:
                _wake(box)
                return
        elif stop.wait(left) or agent.ended:
            _wake(box)
            return
        if due is not None and due != woke_for and agent.late_due() == due and agent.clock.monotonic() >= due:
            woke_for = due
            _wake(box)


class _Kick:
    """Real time inline: what the waker wakes: the step (a step without a pose may be due) and the loop (stop)."""

    def __init__(self, agent: Agent) -> None:
        self.agent = agent

    def wake(self) -> None:
        self.agent.kick.set()
        self.agent.wake.set()


def _wake(box) -> None:
    try:
        box.wake()
    except Exception as e:  # the session is already closing: the loop is on its way out anyway
        log.debug("could not wake the robot loop: %s", e)

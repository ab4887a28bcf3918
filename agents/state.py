"""What one robot knows: every attribute of its agent, their defaults, and the few questions on them that
every concern asks (is a step due, which tick comes next, what time is it on the swarm's clock).

The layers of the agent, each a module and a class on the one below (agents.agent assembles them):
  state     AgentState: the attributes (one object; the compiled sink is handed the ones it reads)
  intake    Intake: the messages that come (bus callbacks, windows on t and seq)
  links     Links: subscriptions by cell and what goes out (state, command, status)
  bodies    Bodies: the obstacles near and the static part of the law's bodies
  lockstep  Lockstep: the tick protocol (wait rule, ticks, the fault view)
  rtsafety  SafeCommand: real time's bodies and the safety rule around the law
  realtime  Realtime: the real-time step (inboxes, late poses, dead reckoning)
  agent     Agent: start and close; the inline runner and the compiled sink wired
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from typing import TYPE_CHECKING, Any

from swarm.proto import keys, protocol
from agents.control import Controller
from swarm.core import law, safety
from swarm.core.clock import WALL
from swarm.proto import window
from swarm.proto.protocol import Cmd, Config, Limits, State
from swarm.core.wake import Runner, Wake

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


class AgentState:
    """The state of one robot's agent (the layers above add behaviour, never attributes of their own but their
    class-level defaults here)."""

    _inputs: list = []
    probed = 0  # real time: neighbours listened for in every cell (_update_probes)
    rt_static: dict = {}  # real time: id -> (x, y, r, R) of the robots the world lists as standing still (_on_bodies)
    rt_static_t = 0.0  # the simulated time of that list
    _poses_by_callback = False  # real time inline: the drive's callback hands over every pose (drive.drain() has none)
    # real time: drains the reference's and every cell's inbox in one call (swarm.net.bus.drainer)
    _drain_cells: Callable[[], list[tuple[str, bytes]]] | None = None
    # real time, under the lock: _on_states's (now, ahead, mono) for _take_one
    _batch: tuple[float | None, float, float] = (None, math.inf, 0.0)
    _hinted_n = 0  # how many of _key_ids (insertion-ordered; only added to, or cleared) went to bus.hint
    _all_sub = None
    _idle = -1  # lock-step under faults: the tick this robot's process is dead or hung at
    _overdue = 0  # lock-step ticks computed without all their inputs (after wait_timeout)
    _world_ups = 0  # times the world's token appeared
    world_alive = False  # the world's token is there
    _announce = False  # lock-step under faults: its session came back; tell the world (FaultStats)
    _rejoin = False  # lock-step: its session came back; the world's next pose ahead is taken
    _rejoin_tick = -1  # lock-step: the tick it rejoined at (it holds still then)
    _clock_needed = 0  # lock-step: clock_0 is the start barrier; later ticks need no clock message
    _rt_seq = -1  # real time: seq of the pose the last command was computed from
    _pose_mono = -math.inf  # real time: when the newest pose came (monotonic)
    _heard_from = math.inf  # real time: states that came before this (monotonic) take the speed bound over their age
    _last_key: str | None = None  # real time: the cell key of its last state
    _since_left = 0  # real time: states put since its last cell change
    _late_next = math.inf  # real time: when a step without a pose is due (monotonic), if none comes before
    periodic = False  # real time: its drive's poses come once a control period (a missing one is lost)

    def __init__(self, bus, cfg: Config, fleet: str = "default", wait_timeout: float = WAIT_TIMEOUT_S,
                 clock=WALL, drive: Drive | None = None, guard=None, faults=None, counters=None, partitions=(),
                 law_file: str | None = None, ahead: bool = False):
        """What a robot knows at its start: its run's config `cfg` on `bus` (fleet `fleet`), its clock, its drive
        (real time; None: the simulated world's, swarm.drives.sim) and guard (agents.guard); lock-step: `faults`, the
        run's (a fault view decides what the law is given: agents.faultview), and wait_timeout. Real time: counters, when given, is an object with `dropped` and `delayed` lists by class (a
        swarm.net.faultbus.FaultBus): reported to the world with every status; partitions, the run's
        (swarm.core.faults.Partition): a neighbour cut off by one is never taken as away while it lasts. law_file: where
        this machine keeps the file of the run's law, when not where the run's config says (swarm robot --law-file).
        ahead (lock-step without faults): each state_(k+1) goes out with cmd_k (agents.lockstep, "States a tick
        ahead")."""
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
        # lock-step without faults: its pose at the next tick as the world integrates it (swarm.core.kinematics, the
        # world's own step: bit for bit while the world applies every command as sent), so that state_(k+1) goes out
        # with cmd_k and the cells of tick k + 1 are subscribed before it (agents.lockstep, "States a tick ahead")
        self.ahead = ahead and cfg.lockstep and self.view is None
        self._pred = [cfg.x, cfg.y, cfg.theta]  # [x, y, theta] at tick _pred_seq (-1: none)
        self._pred_c = [0.0, 0.0, 0.0]  # its compensations (kinematics.step_pose): the world's too while _exact
        self._pred_seq = -1
        self._sent_ahead = -1  # the newest tick whose state went out with the command of the tick before
        self._exact = False  # the chain holds the world's own bits since pose_0: its states may go out ahead
        self.mispredicted = 0  # ticks whose pose was not the one its state had said ahead (the world held a command)
        self.early: dict[int, State] = {}  # lock-step: states of a tick past the next one it computes (_law_tick)
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
        # real time: the step without a pose's deadline, for the waker to wait on without the GIL (_watch)
        wire = protocol._wire
        self.late_timer = wire.Deadline() if wire is not None and not cfg.lockstep and \
            getattr(clock, "machine_monotonic", False) else None
        self._rt_poses: deque = deque()  # real time inline: poses the drive's callback handed over, not taken yet
        # lock-step, no faults: neighbour states taken in C on the bus's thread (Agent.__init__)
        self._state_sink: Any = None
        if self.drive is not None and self.drive.limits is None:
            self.drive.limits = self.limits  # the simulated drive decodes poses with the scenario's bounds
        self._spans = window.spans(cfg.dt, WATCHDOG_S)
        self._tick = cfg.dt if cfg.lockstep else 0.0  # lock-step: a pose's, reference's, state's t is seq x dt
        self.w_pose = window.new(*self._spans, dt=self._tick)  # the world (or localization)
        self.w_clock = window.new(*self._spans, dt=self._tick)  # the world
        self.w_ref = window.new(*self._spans, dt=self._tick)  # the leader
        self.w_bodies = window.new(*self._spans)  # the world (real time under faults)
        self.w_state: dict[int, window.Window] = {}  # robot j
        self.ended = False  # the run this agent serves is over (a new run began): ignore everything
        self.belief: protocol.Pose | None = None  # lock-step under faults: its pose as it knows it at the tick
        self.estop_order = window.StopOrder()  # the operator's: its t is unix time (window.ESTOP_SPAN_S)
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
        self._received = 0  # neighbour states the Python took (states_received: the sink's too)
        self.loop_cpu_s = 0.0  # CPU time of the loop thread handling its wake-ups (thread_time; bench/up_speed.py)
        self.process_cpu_s = 0.0  # CPU time of the whole process (zenoh's threads too) while its loop ran
        self.ticks = 0
        self.skipped = 0
        self.rejoined = 0  # lock-step: times it rejoined the run at a later tick after its session dropped
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

    def end(self) -> None:
        """The run this agent serves is over (any thread): it ignores everything from now on and its
        loop returns."""
        self.ended = True
        if self._state_sink is not None:
            self._state_sink.ended = True
        self.wake.set()

    @property
    def states_received(self) -> int:
        """Neighbour states taken: by the Python (_received) and by the compiled sink (its `taken`)."""
        return self._received + (self._state_sink.taken if self._state_sink is not None else 0)

    @property
    def horizon_s(self) -> float:
        """The safety governor's horizon [s]: the control period, or more in real time (see command())."""
        return self.p[law.P_DT]

    @property
    def subscribed_cells(self) -> set[tuple[int, int]]:
        return set(self._cells)

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
        if k == self._rejoin_tick:
            return True  # it rejoins at k and holds still (Lockstep.tick_lockstep): nothing to wait for
        return k in self.refs and self.clock_seq >= min(k, self._clock_needed) and not self.waiting and \
            (self.view is None or k in self.static_by_seq)

    def _law_tick(self) -> int:
        """Lock-step: the tick whose law this robot computes next: the one under way, or the one after the last it
        did (a tick it started and left for a newer pose, the world having gone on, is never done)."""
        return max(self.k_done + 1, self.k_started)

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

    def sim_time(self, wall: float) -> float | None:
        """Real time: the simulated time at unix time `wall` (None before the world's clock is known)."""
        if self.epoch is None:
            return None
        return (wall - self.epoch) * self.speed

    def _period_wall(self) -> float:
        """Real time: the control period in wall seconds."""
        return self.cfg.dt / max(1e-9, self.speed)

"""What the simulated world holds (world.world's World is built on it): every robot's pose, command, windows and
counters, the fault layers, the referee; set once from the scenario and the options, then moved by the run loops."""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm.proto import keys, protocol, window
from swarm.core import faultgen as fg
from swarm.core import faults as fl
from swarm.core import runid
from swarm.core.clock import WALL
from swarm.proto.protocol import Obstacle, Obstacles
from swarm.core.scenario import Scenario
from swarm.core.wake import Wake
from swarm.core.safety import RAMP_S
from world.realtime_faults import RealtimeFaults
from world.referee import Referee
from swarm.core.faulttable import FaultTable

if TYPE_CHECKING:
    from world.faultworld import WorldFaults
    from world.ros2_fleet import Ros2Fleet

log = logging.getLogger("swarm.world")

WATCHDOG_S = 0.5
TICK_TIMEOUT_S = 1.0
LOST_TIMEOUT_S = 10.0  # s: a leader (or every robot) away this long ends the run with a failure
FINE_DT_S = 0.001


@dataclass(frozen=True)
class WorldOptions:
    """How the world runs a scenario: built once by the command line (`swarm world`'s flags) or a test; World takes
    it, or any of its fields as keywords."""

    lockstep: bool = True
    speed: float = 1.0  # real time: simulated seconds per wall second
    watchdog: float = WATCHDOG_S
    tick_timeout: float = TICK_TIMEOUT_S
    lost_timeout: float = LOST_TIMEOUT_S
    ros2: tuple[str, str, int, str, str] | None = None  # real time, a simulated ROS 2 fleet: flavor, twist, domain,
    # attachment form, distro
    start_timeout: float = 60.0
    trace: bool = False
    process_faults: str = "played"  # lock-step kills and hangs: "signals" when a supervisor really does them
    fine_dt: float = FINE_DT_S  # the integration step of the world's kinematics [s]


class WorldState:
    # real time: the bus inboxes the run loop drains (World.start opens them)
    _cmd_inbox: Any
    _status_inbox: Any
    _faults_inbox: Any

    def __init__(self, bus, scn: Scenario, fleet: str = "default", opts: WorldOptions | None = None, *, clock=WALL,
                 progress=None, **fields):
        """The world of scenario `scn` on `bus`, run as `opts` says (fields: WorldOptions's, each overriding
        opts's: World(bus, scn, fleet, lockstep=False, speed=2.0))."""
        opts = replace(opts or WorldOptions(), **fields)
        self.opts = opts
        lockstep, speed, watchdog, ros2 = opts.lockstep, opts.speed, opts.watchdog, opts.ros2
        tick_timeout, fine_dt, trace, lost_timeout = opts.tick_timeout, opts.fine_dt, opts.trace, opts.lost_timeout
        process_faults = opts.process_faults
        self.bus, self.scn, self.fleet = bus, scn, fleet
        self.clock = clock
        self.lockstep, self.speed = lockstep, speed
        self.watchdog, self.tick_timeout, self.fine_dt = watchdog, tick_timeout, fine_dt
        self.on_progress = progress  # optional callable(protocol.Progress), for a local display
        # real time only: (flavor, twist, domain) of a simulated ROS 2 fleet (world.ros2_fleet): the robots
        # take cmd_vel and give odometry on ROS 2 keys instead of the world's pose and cmd keys
        if ros2 is not None and lockstep:
            raise ValueError("a simulated ROS 2 fleet runs in real time only (odometry carries no tick)")
        self.ros2 = ros2
        self.fleet_ros2: Ros2Fleet | None = None
        # lock-step under faults: membership, commands and static bodies by the shared schedule
        # (world.faultworld); process_faults "signals": a supervisor really kills and stops the robots'
        # processes (the world waits for a restarted or resumed one before its return tick), "played":
        # nobody does, and each robot's process idles through its dead or hung ticks by the schedule
        if process_faults not in ("signals", "played"):
            raise ValueError(f"process_faults must be 'signals' or 'played', got {process_faults!r}")
        self.process_faults = process_faults
        self.wf: WorldFaults | None = None
        if scn.faults and lockstep:
            from world.faultworld import WorldFaults

            self.wf = WorldFaults(scn, watchdog)
        # real time under faults: the commands it receives go through the fault model (swarm.net.faultbus),
        # and it adds up what every robot's own fault bus reports (RealtimeFaults)
        self.fbus = self.rtf = None
        if scn.faults and not lockstep:
            from swarm.net.faultbus import FaultBus

            self.fbus = FaultBus(bus, FaultTable.of(scn.faults, scn.n, scn.dt), fg.WORLD, scn.dt, fleet,
                                 speed=speed, clock=clock)
            self.bus = self.fbus
            self.rtf = RealtimeFaults(scn, self.fbus)
        # every fault event, told on world/events as it happens (lock-step: by tick; real time: by its clock)
        self._timeline = fl.timeline(scn.faults, scn.n) if scn.faults else []
        self.token_gen = [0] * scn.n  # liveliness tokens each robot's id declared (a restart declares a new one)
        self.token_mark: dict[int, int] = {}  # robot -> token_gen when its scheduled kill or hang began
        self.lapsed: set[int] = set()  # robots whose token went away since their scheduled hang began
        self.announced: set[int] = set()  # lapsed robots that said they are back (a FaultStats after the lapse)
        self.run_id = runid.new_run_id(clock)
        self.digest = runid.digest(scn)
        self.leader_timeout = lost_timeout  # s: how long a lost leader (or every robot) may be away before the run ends
        c = scn.control
        self.limits = protocol.Limits.of(scn.n, scn.reach, getattr(c, "v_max", None), getattr(c, "w_max", None))
        self._spans = window.spans(scn.dt, watchdog)
        self.w_cmd = [window.new(*self._spans) for _ in range(scn.n)]  # real time: each robot's commands
        self.w_status = [window.new(*self._spans) for _ in range(scn.n)]
        self.failure: str | None = None  # what ended the run early (metrics "failure")
        self.lost: set[int] = set()  # robots whose token went away during the run
        self.lost_events = 0  # token losses during the run (a robot lost twice counts twice)
        self._strangers: set[int] = set()  # alive robots outside the scenario, already named in the log
        self._running = False
        n = scn.n
        self.n = n
        self.q = [list(map(float, row)) for row in scn.poses]
        self.comp = [[0.0, 0.0, 0.0] for _ in range(n)]
        self.cmd = [(0.0, 0.0)] * n  # the command being applied
        self.cmd_new = [(0.0, 0.0)] * n  # real time: each robot's newest command (applied, held or braked)
        self.cmd_held = 0  # real time: commands that ran out (their until passed without a newer one): braked
        # real time: a command is executed until its `until`, then braked along safety.RAMP_S in steps of `_ramp_h`
        # (never faster than a linear ramp: the safety rule counts on it; docs/runtime.md, "The safety invariant")
        self.until = [-math.inf] * n
        self._gen = [0] * n  # bumps at every change of a robot's command: plan entries of an older one are void
        self._plan: list = []  # heap of (simulated time, robot, gen, step) at which a robot's speed changes
        self._ramp_h = min(scn.dt, RAMP_S / 2.0)
        self.hold_until = [-math.inf] * n  # a robot the world lists as standing does not move before this
        self._deferred: dict[int, tuple] = {}  # (v, w, until, mono, its t) of a command held by a listing
        self.commanded = [False] * n  # it sent a command this run
        self.cmd_t = [-1.0] * n  # real time: the t of the command each robot's drive executes (its poses say it)
        self._cmd_seen = [-math.inf] * n  # real time: when each robot's newest command came (too late or not)
        self.cmd_expired = 0  # real time: commands that came after their until (refused: too late)
        self._died: list[int] = []  # real time: robots whose token went (the loop stops them at its next step)
        self._gone: set[int] = set()  # real time: robots whose token went during the run and is not back
        self._listed: tuple[int, ...] = ()  # real time: the robots the last bodies message listed
        self._listed_t = -math.inf  # and its time
        self.held_by_robot: dict[int, float] = {}  # real time: each robot's share of commands its safety rule held
        self.watchdog_stops = 0  # real time: robots the watchdog stopped
        self._pose_keys = [keys.robot_pose(fleet, i) for i in range(n)]
        self._cmd_ids = {keys.robot_cmd(fleet, i): i for i in range(n)}
        self._status_ids = {keys.robot_status(fleet, i): i for i in range(n)}
        self.cmd_seq = [-1] * n  # lock-step: tick of the newest command
        self.cmd_time = [-math.inf] * n  # sim time (lock-step) or monotonic wall time (real time) of the newest command
        self.stopped = [True] * n
        self.alive = np.zeros(n, bool)
        self.leader_alive = False
        self.table = scn.leader.table()
        self.referee = Referee(scn)
        self.lock = threading.Lock()
        self.wake = Wake()  # set by a bus event the run loop waits for
        self._await = -1  # lock-step: the tick whose commands are awaited
        self._awaited: set[int] = set()  # lock-step: robots whose command of _await had not come (see _on_cmd)
        self._dec_cmd = protocol.decoder("cmd", self.limits)
        self._pending: dict[int, tuple[float, float]] = {}
        # lock-step without faults: the tick a command's own thread may finish (world.lockstep_loop, "The last
        # command's thread"), and each robot's pose of the next tick, stepped as its command came
        self._inline_from = -1  # the run loop waits at this tick, its bookkeeping done (-1: nobody may advance it)
        self.taken_over = 0  # ticks a command's thread finished
        self._inline_busy = False  # a command's thread is publishing the tick it advanced to
        self._inline_later: tuple | None = None  # what it leaves the run loop: the step's wait-rule check
        self._next: list = [None] * n  # per robot: (tick of its command, next pose, compensations, the pose encoded)
        self.bad = protocol.BadMessages(log)
        self.robot_bad = protocol.Claims()  # the robots' own counts of bad messages, bounded
        self.misses = 0
        self._miss_events = 0  # lock-step ticks with a miss (for the log's rate limit)
        # lock-step: pairs of robots a tick that the agents' wait rule could not cover (see _check_wait_rule)
        self.step_bound = keys.lockstep_step_bound(scn.reach, scn.cell_side)
        self.wait_reach = keys.lockstep_wait_reach(scn.reach, scn.cell_side)
        self.overruns = 0
        self._cells_hist: tuple[np.ndarray, np.ndarray] | None = None  # lock-step: cells at k-2, k-3
        self._short_step = False  # lock-step: no robot moved more than L in the last step checked
        self.round_trips: list[float] = []  # real time: s from publishing a pose to the command computed from it
        self._pose_sent: dict[float, float] = {}
        self.k = 0
        self.t = 0.0
        self.trace: list[np.ndarray] | None = [] if trace else None
        self.trace_t: list[float] = []  # the simulated time of each trace row
        self.samples_missed = 0  # real time: control periods the world fell behind and did not sample
        self._handles: list = []
        self._state0: set[int] = set()
        self._prime = None
        self._last_progress = -math.inf
        self._obstacles = protocol.encode(Obstacles(tuple(Obstacle(*map(float, o)) for o in scn.obstacles)))

"""The simulated world: every robot's exact-arc kinematics, the obstacles, the clock, the referee.

    metrics = run_world(bus, clock, scenario, WorldOptions(lockstep=True), stop_event)
    # which is: World(...).start() (queryables, subscriptions, liveliness token), .wait_ready()
    # (every robot and the leader alive, or NotReady naming the missing), .run() (the metrics of
    # docs/metrics.md from ground truth), .close()

It serves world/obstacles and world/config/<id> (each robot's slice of the scenario),
publishes robot/<id>/pose, world/snapshot, world/clock and world/progress, and takes
robot/<id>/cmd. Watchdog: a robot whose newest command is older than `watchdog` seconds is
stopped (v = w = 0) until a new command comes.

Lock-step (the world owns the clock): publish pose_0 of every robot, wait until every robot's
state_0 has been delivered (the start barrier), publish clock_0; then per tick k: wait for
cmd_k of every live robot (or `tick_timeout` wall seconds: then the missing robots hold their
last command and a miss is counted), sample the metrics, move every robot one exact arc of dt,
publish clock_(k+1) and pose_(k+1). Deterministic: equal to `swarm sim` step for step.
Real time: on a fine time grid (default 1 ms of simulated time) the world holds each robot's
newest command and integrates it lazily (one exact arc per event), publishes each robot's pose once per control period (staggered over the period),
and clock and snapshot every period; `speed` sets simulated seconds per wall second.
"""

from __future__ import annotations

import heapq
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from world.ready import NotReady, wait_ready
from swarm.net import presence
from swarm.proto import keys, protocol, window
from swarm.core import faultgen as fg
from swarm.core import faults as fl
from swarm.core import kinematics, runid
from swarm.core.clock import WALL, said_step
from swarm.process import settle_heap
from swarm.proto.protocol import Clock, Obstacle, Obstacles, Pose, ProtocolError, RobotSnap, Run, Snapshot
from swarm.core.geometry import pairs_within
from swarm.core.scenario import Scenario
from swarm.core.wake import Wake
from swarm.core.safety import BODIES_HOLD_S, RAMP_S
from world.estop import EstopLog
from world.realtime_faults import RealtimeFaults
from world.referee import Referee, log_collisions
from swarm.core.faulttable import FaultTable, first_tick

if TYPE_CHECKING:
    from world.faultworld import WorldFaults
    from world.ros2_fleet import Ros2Fleet

log = logging.getLogger("swarm.world")

WATCHDOG_S = 0.5
TICK_TIMEOUT_S = 1.0
LOST_TIMEOUT_S = 10.0  # s: a leader (or every robot) away this long ends the run with a failure
FINE_DT_S = 0.001
PROGRESS_PERIOD_S = 0.25  # wall seconds between progress messages
BODIES_EVERY_S = 0.2  # real time: the bodies message goes out every period while it lists a robot, else this often
BODIES_SILENT_S = 0.25  # real time: a robot stopped after commanding is listed once no command came for this long
ROUND_TRIP_HISTORY_S = 5.0  # real time: poses remembered for round trips (simulated s; far past the watchdog)


class World:
    def __init__(self, bus, scn: Scenario, fleet: str = "default", lockstep: bool = True, speed: float = 1.0,
                 watchdog: float = WATCHDOG_S, tick_timeout: float = TICK_TIMEOUT_S, fine_dt: float = FINE_DT_S,
                 trace: bool = False, progress=None, clock=WALL, lost_timeout: float = LOST_TIMEOUT_S,
                 ros2: tuple[str, str, int, str, str] | None = None, process_faults: str = "played"):
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
        self.w_cmd = [window.Window(*self._spans) for _ in range(scn.n)]  # real time: each robot's commands
        self.w_status = [window.Window(*self._spans) for _ in range(scn.n)]
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

    # ------------------------------------------------------------------ wiring

    def start(self) -> None:
        f, ev = self.fleet, self.event
        self._handles.append(self.bus.serve(keys.world_obstacles(f), lambda key: self._obstacles))
        self._handles.append(self.bus.serve(keys.world_config_any(f), self._config))
        self._run_reply = protocol.encode(Run(run=self.run_id, digest=self.digest, robots=self.n,
                                              lockstep=self.lockstep, scenario=runid.canonical(self.scn)))
        self._handles.append(self.bus.serve(keys.world_run(f), lambda key: self._run_reply))
        if self.lockstep:
            self._handles.append(self.bus.subscribe(keys.robot_any(f, "cmd"), self._on_cmd))
            self._handles.append(self.bus.subscribe(keys.robot_any(f, "status"), lambda k, b: ev(("status", k, b))))
            if self.wf is not None:
                self._handles.append(self.bus.subscribe(keys.robot_any(f, "faults"), lambda k, b: ev(("faults", k, b))))
        elif self.ros2 is not None:  # real time, ROS 2 robots: cmd_vel in, odometry out (world.ros2_fleet)
            from world.ros2_fleet import Ros2Fleet

            flavor, twist, domain, attachment, distro = self.ros2
            self.fleet_ros2 = Ros2Fleet(self.bus, [tuple(map(float, p)) for p in self.scn.poses], flavor, twist, domain,
                                        attachment=attachment, distro=distro)
            self.fleet_ros2.start()
            self._status_inbox = self.bus.inbox(keys.robot_any(f, "status"), depth=8 * self.n + 64)
            self._handles.append(self._status_inbox)
        else:  # real time: the run loop drains these itself (no Python on zenoh's threads, no wait for the GIL)
            self._cmd_inbox = self.bus.inbox(keys.robot_any(f, "cmd"), depth=8 * self.n + 64)
            self._status_inbox = self.bus.inbox(keys.robot_any(f, "status"), depth=8 * self.n + 64)
            self._handles += [self._cmd_inbox, self._status_inbox]
            if self.rtf is not None:  # each robot's fault counters, with its statuses
                self._faults_inbox = self.bus.inbox(keys.robot_any(f, "faults"), depth=8 * self.n + 64)
                self._handles.append(self._faults_inbox)
        if self.ros2 is None:  # every robot's command and status keys: zenoh resolves each one's route once
            for key in [*self._cmd_ids, *self._status_ids]:  # (ZenohBus.hint), not for every message
                self.bus.hint(key)
        self._handles.append(self.bus.watch_alive(keys.alive_any(f, "robot"), lambda k, up: ev(("alive", k, up))))
        self._handles.append(self.bus.watch_alive(keys.alive_any(f, "leader"), lambda k, up: ev(("leader", k, up))))
        if self.lockstep:  # the start barrier: every robot's state_0 (unsubscribed once passed)
            self._prime = self.bus.subscribe(keys.cell_all(f), lambda k, b: ev(("state", k, b)))
        # declare the snapshot's publisher now, so zenoh knows of the viewers and recorders already
        # subscribed by tick 0 (wanted() would otherwise say no for the first snapshot)
        self.bus.wanted(keys.world_snapshot(f))
        self._handles.append(presence.announce(self.bus, f, "world", run=lambda: self.run_id))
        self.estop = EstopLog(self.bus, f, now=lambda: (self.t, self.k))  # logged, told, counted (world.estop)
        self.estop.start()
        self._handles.append(self.estop)
        self.publish_run()

    def publish_run(self) -> None:
        """Say that a run begins (robots and the leader of an earlier run start afresh on it)."""
        self.bus.put(keys.world_run(self.fleet), protocol.encode(
            Run(run=self.run_id, digest=self.digest, robots=self.n, lockstep=self.lockstep, scenario="")),
            reliable=True)

    def close(self) -> None:
        if self.fbus is not None:
            self.fbus.detach()
        if self.fleet_ros2 is not None:
            self.fleet_ros2.close()
            self.fleet_ros2 = None
        if self._prime is not None:
            self._prime.close()
            self._prime = None
        for h in self._handles[::-1]:
            h.close()
        self._handles.clear()

    def _config(self, key: str) -> bytes | None:
        parsed = keys.parse(key)
        if parsed is None or parsed.kind != "config" or parsed.id is None or parsed.id >= self.n:
            return None
        return protocol.encode(runid.robot_config(self.scn, parsed.id, self.lockstep, self.run_id, self.digest))

    # ------------------------------------------------------------------ events

    def event(self, item) -> None:
        """A bus event, on the bus's thread: update under the lock; wake the run loop when the
        awaited tick's commands are complete (or a robot came or went)."""
        with self.lock:
            self._handle(item)
            due = item[0] in ("alive", "leader", "state") or (self._await >= 0 and not self._awaited)
        if due:
            self.wake.set()

    _leader_back = False  # the leader's token came back during the run (lock-step: repeat the clock for it)
    estop: EstopLog | None = None  # the emergency stop's log (world.estop), once started
    leader_ups = 0  # times the leader's token appeared

    def _on_cmd(self, key: str, data: bytes) -> None:
        """Lock-step: a command, on the bus's thread. event(("cmd", key, data)) in few steps: 37 of these a
        tick run on zenoh's threads. The run loop is woken when the last awaited command came (_awaited: it
        sets it from _missing() at each wake-up; a robot that came or went wakes it anyway)."""
        i = self._cmd_ids.get(key)
        if i is None:  # not a command key of this world: named the long way
            self.event(("cmd", key, data))
            return
        try:
            c = self._dec_cmd(data)
        except ProtocolError as e:
            with self.lock:
                self.bad.reject(key, e)
            return
        with self.lock:
            try:
                self._take_cmd(i, c)
            except ProtocolError as e:
                self.bad.reject(key, e)
                return
            due = self._await >= 0 and not self._awaited
        if due:
            self.wake.set()

    def _take_cmd(self, i: int, c: protocol.Cmd) -> None:
        """Lock-step (under the lock): only the command of the tick under way counts (the world publishes
        tick k before anyone can answer it); a later seq is refused, an earlier one is late (stale), and so is
        one whose t is not its seq's tick time (forged: docs/protocol.md, Windows)."""
        if not abs(c.t - c.seq * self.scn.dt) <= window.TICK_EPS:
            raise ProtocolError(f"a command of tick {c.seq} with t {c.t:g}: lock-step, and t is not seq x dt")
        if c.seq == self.k and c.seq > self.cmd_seq[i]:
            self.cmd_seq[i] = c.seq
            self._pending[i] = (c.v, c.w)
            self._awaited.discard(i)
        elif c.seq > self.k:
            raise ProtocolError(f"a command for tick {c.seq} while the world is at tick {self.k}")
        else:
            self.bad.stale += 1

    def _missing(self) -> list[int]:
        """Live robots whose command for the awaited tick has not come (call under the lock)."""
        k = self._await
        wf = self.wf
        return [i for i in range(self.n) if self.alive[i] and self.cmd_seq[i] < k and (wf is None or wf.running(i, k))]

    def _handle(self, item) -> None:
        tag, key, data = item
        try:
            if tag in ("alive", "leader"):
                self._on_alive(tag, key, data)
                return
            i = self._status_ids.get(key) if tag == "status" else None  # the common case: a key of ours
            if i is None:
                parsed = keys.parse(key)
                if parsed is None or parsed.id is None or parsed.id >= self.n:
                    raise ProtocolError(f"not a robot of this world: {key!r}")
                i = parsed.id
            if tag == "cmd":  # lock-step (real time takes its commands in _take_commands)
                self._take_cmd(i, protocol.decode(data, "cmd", None, self.limits))
            elif tag == "status":
                st = protocol.decode(data, "status", None, self.limits)
                if self.bad.verdict(key, self._after_return(i, self.w_status[i], st.t, int(round(st.t / self.scn.dt))),
                                    "the status's t"):
                    self.robot_bad.take(i, st.bad, self.clock.monotonic())
                    if st.held is not None:
                        self.held_by_robot[i] = st.held
            elif tag == "state":
                if protocol.decode(data, "state", i, self.limits).seq == 0:
                    self._state0.add(i)
            elif tag == "faults":
                s = protocol.decode(data, "faultstats", None, self.limits)
                # faults come only when self.wf is set (start subscribes them then)
                if s.seq > self.k or not self.wf.running(i, s.seq):  # type: ignore[union-attr]
                    # a process stopped before its first tick (hung at tick 0) says it is back with tick 0's
                    # counters, all zero: taken as its word only
                    zero = not any((s.dropped_state, s.dropped_pose, s.dropped_ref, s.delayed_state, s.delayed_pose,
                                    s.delayed_ref, s.max_age))
                    if not (s.seq == 0 and i in self.lapsed and zero):
                        raise ProtocolError(f"fault counters of tick {s.seq}, when robot {i} is not running then "
                                            f"(the world is at tick {self.k})")
                else:
                    self.wf.take_stats(i, s)  # type: ignore[union-attr]  # as above: self.wf is set
                if i in self.lapsed and self.alive[i]:
                    self.announced.add(i)  # a robot back from a hang past its lease: its subscriptions are back
        except ProtocolError as e:
            self.bad.reject(key, e)

    def _on_alive(self, tag: str, key: str, up: bool) -> None:
        """Liveliness (under the lock): robots and the leader come and go. A robot id outside the
        scenario is named once in the log; a robot lost during the run is counted."""
        parsed = keys.parse(key)
        if parsed is None or parsed.kind != "alive" or parsed.id is None:
            return
        if tag == "leader":
            self.leader_alive = up
            if up:
                self.leader_ups += 1
                if self._running:
                    self._leader_back = True
            return
        i = parsed.id
        if i >= self.n:
            if up and i not in self._strangers:
                self._strangers.add(i)
                log.warning("robot %d is alive but not in this world's scenario (%d robots: 0..%d); it takes no "
                            "part in the run (started with another scenario or fleet?)", i, self.n, self.n - 1)
            return
        if up:
            self.token_gen[i] += 1
        elif i in self.token_mark:
            self.lapsed.add(i)
        if not up and self.alive[i] and self._running:
            if self.wf is not None and not self.wf.running(i, self.k):  # a scheduled kill or hang: membership
                log.info("robot %d's token is gone at t = %g s (its process is %s by the fault schedule)", i,
                         self.t, "dead" if self.wf.dead(i, self.k) else "hung")  # follows the schedule
            elif self.rtf is not None and self.rtf.away(i, self._now_rt()):  # real time: as scheduled
                log.info("robot %d's token is gone at t = %g s (its process is %s by the fault schedule)", i,
                         self._now_rt(), fl.process_state(cast(fl.Faults, self.scn.faults), i, self._now_rt()))
            else:
                self.lost.add(i)
                self.lost_events += 1
                log.warning("robot %d lost at t = %g s (its liveliness token is gone)", i, self.t)
        if not up and self.alive[i] and self._running and not self.lockstep:
            self._died.append(i)  # the loop stops it at its next fine step (a dead robot is a body on the floor)
            self._gone.add(i)
        if up:
            self._gone.discard(i)
        self.alive[i] = up
        if up:
            self.w_cmd[i].reset()
            self.w_status[i].reset()

    def _after_return(self, i: int, w: window.Window, t: float, seq: int) -> str:
        """w.check(t, seq) for robot i's message; but in real time under faults, a jump right after robot i's
        scheduled hang or kill ended is the schedule's gap, not a bad message: the window starts again there.
        (Its returning token resets the window too, but its first messages can come before the token does.)"""
        v = w.check(t, seq)
        if v == window.JUMP and self.rtf is not None and self.rtf.returned(i, self._now_rt(), self._spans[0]):
            w.reset()
            v = w.check(t, seq)
        return v

    def _now_rt(self) -> float:
        """Real time: the simulated time now by the wall clock (the loop's self.t lags it by a fine step)."""
        epoch = getattr(self, "epoch", None)
        return self.t if epoch is None else max(self.t, (self.clock.time() - epoch) * self.speed)

    def wait_ready(self, timeout_s: float, stop: threading.Event | None = None) -> None:
        """Wait until every robot and the leader are alive, timeout_s after the last one that came (world.ready);
        NotReady names the missing ones."""
        def missing() -> list[str]:
            with self.lock:
                return ([] if self.leader_alive else ["leader"]) + [f"robot {i}" for i in np.flatnonzero(~self.alive)]

        def wake(s: float) -> None:
            self.wake.wait(s)
            self.wake.clear()
        wait_ready(missing, wake, self.clock.monotonic, timeout_s, stop)

    # ------------------------------------------------------------------ publishing

    def _publish_tick(self, t: float, seq: int, epoch: float = 0.0) -> None:
        f = self.fleet
        self.bus.put(keys.world_clock(f), protocol.encode(Clock(t=t, seq=seq, epoch=epoch, speed=self.speed)),
                     reliable=True)
        self._publish_poses(t, seq)

    def _publish_poses(self, t: float, seq: int) -> None:
        # the snapshot first: it is best effort (a viewer must never hold the world back), and at the
        # head of the burst it finds the send queue empty instead of behind N reliable poses
        self._publish_snapshot(t, seq)
        wf = self.wf
        for i in range(self.n):
            if wf is None or wf.running(i, seq):  # under faults: only to robots whose process runs at seq
                self._publish_pose(i, t, seq)

    def _publish_pose(self, i: int, t: float, seq: int) -> None:
        x, y, th = self.q[i]
        # lock-step: reliable (a lost pose would cost a tick timeout); real time: best effort, like a sensor (a
        # robot goes on without one), and a robot cut off from the router must not block the router's thread
        # that forwards every other pose (zenoh blocks a reliable put to a full queue for up to 5 s)
        self.bus.put(self._pose_keys[i], protocol.encode(Pose(t=t, seq=seq, x=x, y=y, theta=th, cmd=self.cmd_t[i])),
                     reliable=self.lockstep)

    def _publish_snapshot(self, t: float, seq: int) -> None:
        key = keys.world_snapshot(self.fleet)
        if not self.bus.wanted(key):  # nobody watches or records: skip building it (the world is on every tick's path)
            return
        snap = Snapshot(t=t, seq=seq, robots=tuple(
            RobotSnap(i, x, y, th, self.cmd[i][0], self.cmd[i][1], self.stopped[i], bool(self.alive[i]))
            for i, (x, y, th) in enumerate(self.q)))
        self.bus.put(key, protocol.encode(snap))

    def _sample(self, t: float) -> None:
        q = np.array(self.q)
        if self.trace is not None:
            self.trace.append(q)
            self.trace_t.append(t)
        xl, yl, thl, _v, _w = kinematics.leader_state(self.table, t)
        self.referee.sample(t, q, self._counted(), (xl, yl, thl),
                            None if self.wf is None else self.wf.frozen(self.k))
        if self.referee.new_collisions:
            log_collisions(self.referee, t)

    def _counted(self) -> np.ndarray:
        """The robots convergence and errors are over: the live ones; under faults (lock-step) those whose
        process is not dead now and is alive at the end (the simulator's definition)."""
        wf = self.wf
        if wf is None:
            return self.alive
        return np.array([not wf.dead(i, self.k) and wf.alive_end[i] for i in range(self.n)], bool)

    def _not_dead(self) -> int:
        wf = self.wf
        if wf is None:
            if self.rtf is None:
                return int(self.alive.sum())
            # real time under faults: a hung robot's token lapses after the lease, but its process is not dead
            now, faults = self._now_rt(), cast(fl.Faults, self.scn.faults)  # the faults self.rtf plays
            return sum(1 for i in range(self.n) if self.alive[i] or fl.process_state(faults, i, now) == "hung")
        return sum(1 for i in range(self.n) if not wf.dead(i, self.k))

    def progress(self) -> protocol.Progress:
        ref = self.referee
        d = ref.min_rr
        conv = ref.converged_at()
        return protocol.Progress(t=self.t, seq=self.k, duration=self.scn.duration, robots=self.n,
                                 alive=self._not_dead(), converged=ref.converged_now, frozen=ref.frozen_now,
                                 min_distance=d if math.isfinite(d) else -1.0, misses=self.misses,
                                 bad=self.bad_total(), collisions=ref.collisions, overruns=self.overruns,
                                 min_obstacle=ref.min_ro if math.isfinite(ref.min_ro) else -1.0,
                                 position_error=ref.pmax if ref.samples and ref.alive_now else -1.0,
                                 orientation_error=ref.emax if ref.samples and ref.alive_now else -1.0,
                                 converged_at=-1.0 if conv is None else conv,
                                 last_freeze=-1.0 if ref.last_frozen_t is None else ref.last_frozen_t,
                                 dropped=self._dropped(), hung=self._hung_now(),
                                 held=-1.0 if self.lockstep or self.held_back() is None
                                 else cast(float, self.held_back()),
                                 stranded=ref.stranded_now)

    def _dropped(self) -> int:
        if self.wf is not None:
            return sum(self.wf.totals()[0])
        return 0 if self.rtf is None else sum(self.rtf.totals()[0])

    def bad_total(self) -> int:
        fleet = self.fleet_ros2
        ros = 0 if fleet is None else fleet.bad.count + fleet.dropped_no_attachment
        return self.bad.count + sum(self.robot_bad.values()) + ros

    def _report(self, force: bool = False) -> None:
        now = self.clock.monotonic()
        if force or now - self._last_progress >= PROGRESS_PERIOD_S:
            self._last_progress = now
            p = self.progress()
            self.bus.put(keys.world_progress(self.fleet), protocol.encode(p))
            if self.on_progress is not None:
                self.on_progress(p)

    # ------------------------------------------------------------------ the run

    def run(self, stop: threading.Event | None = None, started: float | None = None) -> dict:
        """Run to the scenario's duration (or until stop is set, or a failure ends it); returns the
        metrics, with `failure` saying what ended the run early (None if nothing did)."""
        stop = stop or threading.Event()
        started = time.perf_counter() if started is None else started
        self._run_started = time.perf_counter()
        interrupted = False
        self._running = False  # from the start barrier on (robots of an earlier run turn to this one before it)
        try:
            if self.lockstep:
                interrupted = self._run_lockstep(stop)
            else:
                self.clock.anchor()  # take up a step of the system clock made before this run
                interrupted = self._run_realtime(stop)
                said_step(self.clock, log, "world", self.run_id)
        finally:
            self._running = False
            self._report(force=True)
        if self.failure:
            log.error("world: the run ended early: %s", self.failure)
        if not self._counted().any():  # the last step had no live robot: nothing is converged, no final error
            self.referee.alive_now = 0
            self.referee.good_since = None
        extra = dict(cmd_misses=self.misses, bad_messages=self.bad_total(), steps=self.k,
                     **({"lockstep_overruns": self.overruns} if self.lockstep else {}),
                     robots_alive_at_end=int(self.alive.sum()), robots_lost=self.lost_events, lost_robots=sorted(self.lost),
                     run_wall_s=time.perf_counter() - self._run_started, failure=self.failure, run_id=self.run_id,
                     scenario_digest=self.digest, stale_messages=self.bad.stale, **self._latency(),
                     **({} if self.lockstep else {"samples_missed": self.samples_missed}))
        if self.wf is not None:  # messages_dropped, faults {...}, robots_alive_at_end by the schedule
            extra.update(self.wf.metrics(self._not_dead(), self.t))
        elif self.rtf is not None:  # real time: counted as it happened (docs/faults.md)
            extra.update(self.rtf.metrics(self.t, self.cmd_held, self.watchdog_stops))
        if not self.lockstep:
            extra.update(self._realtime_metrics())
        if self.estop is not None:
            extra.update(self.estop.metrics())
        return self.referee.metrics(time.perf_counter() - started, interrupted,
                                    "lockstep" if self.lockstep else "realtime", **extra)

    def _absent(self) -> str | None:
        """What the run cannot go on without, now: the leader, or every robot (None if both are here)."""
        with self.lock:
            if not self.leader_alive:
                return "leader"
            if self.n and not self.alive.any():
                return "robots"
        return None

    def _hold(self, stop: threading.Event) -> bool:
        """Lock-step, before a tick: while the leader (or every robot) is away, hold the tick, up to
        leader_timeout; a restarted leader is given the clock again so it catches up. False if they did
        not come back (self.failure says who) or stop was set."""
        what = self._absent()
        if what is None:
            return True
        log.warning("world: %s away at t = %g s; holding tick %d for up to %g s", "the leader" if what == "leader"
                    else "every robot", self.t, self.k, self.leader_timeout)
        end = self.clock.monotonic() + self.leader_timeout
        while not stop.is_set():
            what = self._absent()
            if what is None:
                self._resend_clock()
                return True
            if self.clock.monotonic() >= end:
                self.failure = (f"leader lost at t = {self.t:g} s" if what == "leader"
                                else f"no robot alive at t = {self.t:g} s")
                return False
            self.wake.wait(0.1)
            self.wake.clear()
        return False

    def _resend_clock(self) -> None:
        """Lock-step: the current tick's clock again, for a leader that restarted (it publishes the
        references from this tick on when it hears the clock)."""
        with self.lock:
            back, self._leader_back = self._leader_back, False
        if back:
            self.bus.put(keys.world_clock(self.fleet), protocol.encode(
                Clock(t=max(0, self.k - 1) * self.scn.dt, seq=max(0, self.k - 1), epoch=0.0, speed=1.0)), reliable=True)

    def _latency(self) -> dict:
        if not self.round_trips:
            return {}
        rt = np.array(self.round_trips) * 1e3
        return {"round_trip_ms_median": float(np.median(rt)), "round_trip_ms_p99": float(np.percentile(rt, 99)),
                "round_trips": int(rt.size)}

    def _run_lockstep(self, stop: threading.Event) -> bool:
        scn, dt = self.scn, self.scn.dt
        n_steps = scn.steps
        wf = self.wf
        # start barrier: pose_0 to everyone, then wait until every robot's state_0 is delivered; pose_0 is
        # repeated for robots still missing (a robot of an earlier run may have ignored the first one while
        # it turned to this run)
        if wf is not None:
            self._begin_faults(0)
            # a robot returning at tick 1 (hung at tick 0) is waited for before tick 0 begins, as one returning at
            # k + 1 is before clock k in the loop below (it was not: the run went on without it, counted it lost)
            if not self._await_returns(1, stop):
                return stop.is_set()
            self._publish_bodies(0)
        self._publish_poses(0.0, 0)
        end = self.clock.monotonic() + max(5.0, 5 * self.tick_timeout)
        again = self.clock.monotonic() + 0.25
        while not stop.is_set() and self.clock.monotonic() < end:
            with self.lock:
                missing = [i for i in range(self.n) if i not in self._state0 and (wf is None or wf.running(i, 0))]
            if not missing:
                break
            if self.clock.monotonic() >= again:
                again = self.clock.monotonic() + 0.25
                if wf is not None:
                    self._publish_bodies(0)
                for i in missing:
                    self._publish_pose(i, 0.0, 0)
            self.wake.wait(0.05)
            self.wake.clear()
        if self._prime is not None:
            self._prime.close()
            self._prime = None
        self.bus.put(keys.world_clock(self.fleet), protocol.encode(Clock(t=0.0, seq=0, epoch=0.0, speed=1.0)),
                     reliable=True)
        with self.lock:
            self._running = True
        # without faults the check of a step's wait rule (it only counts) runs once the next tick's poses are
        # out: off the path every robot waits on
        later = None
        try:
            for k in range(n_steps + 1):
                self.k, self.t = k, k * dt
                t = self.t
                if k > 0:
                    if not self._hold(stop):
                        return stop.is_set()
                    if wf is not None:
                        self._begin_faults(k)
                        # before clock k: the leader answers it with the reference of k + 1, which a robot
                        # returning at k + 1 must hear
                        if not self._await_returns(k + 1, stop):
                            return stop.is_set()
                        self._publish_bodies(k)
                    elif not self.alive.all():  # robots lost: every robot learns where they stand, each tick
                        self._publish_lost(k)
                    self._publish_tick(t, k)
                if wf is None:
                    self._sample(t)
                    self._report()
                    if later is not None:  # the last step's check, now that this tick's poses are out
                        self._check_wait_rule(*later)
                        later = None
                    if k == n_steps:
                        break
                else:  # the supervisor acts on the world's tick
                    self._report(force=self._signal_due(k))
                # wait for cmd_k of every live robot (under faults: of every robot whose process runs at k, at
                # the last tick too: their fault counters come just before their commands)
                deadline = self.clock.monotonic() + self.tick_timeout
                with self.lock:
                    self._await = k
                    self._awaited = set(self._missing())
                    ups = self.leader_ups
                while True:
                    if stop.is_set():
                        return True
                    self._resend_clock()  # a leader that came back during this tick hears the clock at once
                    with self.lock:
                        waiting = self._missing()
                        self._awaited = set(waiting)
                        if not waiting:
                            self._await = -1
                            pending, self._pending = self._pending, {}
                            break
                        left = deadline - self.clock.monotonic()
                        # no reference without the leader: a tick whose leader is away, or came back during it,
                        # is held (no miss) until the leader is back and answered
                        away = left <= 0 and (not self.leader_alive or self.leader_ups != ups)
                        ups = self.leader_ups
                        if left <= 0 and not away:
                            self.misses += len(waiting)
                            self._miss_events += 1
                            if self._miss_events <= 10 or self._miss_events % 100 == 0:
                                log.warning("world: no command from robot%s %s for tick %d (t = %g s) within %g s; %s "
                                            "held (%d ticks with misses so far)", "s" if len(waiting) > 1 else "",
                                            ", ".join(map(str, waiting[:8])), k, t, self.tick_timeout,
                                            "they are" if len(waiting) > 1 else "it is", self._miss_events)
                            self._await = -1
                            pending, self._pending = self._pending, {}
                            break
                    if away:  # no reference without the leader: hold the tick until it is back (no miss)
                        if not self._hold(stop):
                            return stop.is_set()
                        deadline = self.clock.monotonic() + self.tick_timeout
                        continue
                    self.wake.wait(min(left, 0.5))
                    self.wake.clear()
                before = np.array(self.q)[:, :2]
                if wf is not None:  # the commands the fault schedule lets through, held, braked or stopped
                    applied = wf.apply(k, pending)
                    self._sample(t)  # under faults once the laws of k are known (their freezes are the metrics')
                    if k == n_steps:
                        break
                for i in range(self.n):
                    if wf is not None:
                        self.cmd[i] = applied[i]
                        self.stopped[i] = wf.stopped[i]
                        if i in pending:
                            self.cmd_time[i] = t
                    elif not self.alive[i]:  # lost (its token went): it stops where it is, a body on the floor
                        pending.pop(i, None)
                        self.cmd[i] = (0.0, 0.0)
                        self.stopped[i] = True
                    elif i in pending:
                        self.cmd[i] = pending.pop(i)
                        self.cmd_time[i] = t
                        self.stopped[i] = False
                    elif t - self.cmd_time[i] > self.watchdog + 1e-9:  # watchdog: stop a silent robot
                        self.cmd[i] = (0.0, 0.0)
                        self.stopped[i] = True
                    v, w = self.cmd[i]
                    kinematics.step_pose(self.q[i], self.comp[i], v, w, dt)
                    if not all(math.isfinite(a) for a in self.q[i]):
                        self.failure = (f"robot {i}'s pose became non-finite at tick {k + 1} (t = {t + dt:g} s): "
                                        f"x, y, theta = {self.q[i]} after the command (v {v:g}, w {w:g})")
                        return stop.is_set()
                if wf is None:
                    later = (t + dt, before, self.alive.copy())
                else:
                    self._check_wait_rule(t + dt, before)
        finally:
            if later is not None:
                self._check_wait_rule(*later)
        return stop.is_set()

    # ------------------------------------------------------------------ lock-step under faults

    def _begin_faults(self, k: int) -> None:
        """Tick k's process events (world.faultworld): counted, logged, and noted for the waits of
        _await_returns (the token count when a robot's kill or hang began); every event at k told on
        world/events."""
        self._tell_events(k * self.scn.dt, k, lambda t: first_tick(t, self.scn.dt) <= k)
        for i, kind in self.wf.begin(k):  # type: ignore[union-attr]  # the run loop calls this under faults only
            log.info("world: fault at tick %d (t = %g s): robot %d %s", k, k * self.scn.dt, i,
                     {"kill": "killed", "restart": "restarted", "hang": "hung", "resume": "resumed"}[kind])
            with self.lock:
                self.lapsed.discard(i)
                self.announced.discard(i)
                if kind in ("kill", "hang"):
                    self.token_mark[i] = self.token_gen[i]
                else:
                    self.token_mark.pop(i, None)
                    self.w_status[i].reset()  # its statuses resume after a gap

    def _tell_events(self, t: float, seq: int, due) -> None:
        """Publish on world/events every fault event of the timeline that is due (due(t_event) true)."""
        while self._timeline and due(self._timeline[0][0]):
            te, event, robots, detail = self._timeline.pop(0)
            self.bus.put(keys.world_events(self.fleet), protocol.encode(
                protocol.Event(t=te, seq=seq, event=event, robots=robots, detail=detail)), reliable=True)

    def _hung_now(self) -> int:
        f = self.scn.faults
        if not f or not f.hangs:
            return 0
        if self.wf is not None:
            return sum(1 for i in range(self.n) if self.wf.schedule.state(i, self.k) == fg.PROC_HUNG)
        return sum(1 for i in range(self.n) if fl.process_state(f, i, self.t) == "hung")

    def _signal_due(self, k: int) -> bool:
        """A supervisor acts at tick k (a kill or hang begins, or a resume is next): report progress now."""
        wf: WorldFaults = self.wf  # type: ignore[assignment]  # the run loop calls this under faults only
        return any(wf.returning(i, k + 1) == "resume" or (wf.running(i, k - 1) and not wf.running(i, k))
                   for i in range(self.n)) if k > 0 else False

    def _await_returns(self, k: int, stop: threading.Event) -> bool:
        """Lock-step under faults, before the tick before k: with a supervisor that really kills and stops processes
        (process_faults "signals"), wait for every robot returning at k, up to lost_timeout: a restarted
        robot's new process (a token declared after the kill: its subscriptions came before it); a resumed
        one, whose token lapsed (the supervisor stops a process longer than its lease, so its session surely
        closed) and came back, and which said so (its fault counters again, sent once its session and
        subscriptions are back). False (self.failure says who) if one did not come."""
        if self.process_faults != "signals":
            return True
        wf: WorldFaults = self.wf  # type: ignore[assignment]  # the run loop calls this under faults only
        back = [(i, wf.returning(i, k)) for i in range(self.n) if wf.returning(i, k) is not None]
        if not back:
            return True

        def missing() -> list[int]:
            with self.lock:
                out = []
                for i, kind in back:
                    mark = self.token_mark.get(i, -1)
                    if not self.alive[i] or (kind == "restart" and self.token_gen[i] <= mark) or \
                            (kind == "resume" and (i not in self.lapsed or i not in self.announced)):
                        out.append(i)
                return out

        end = self.clock.monotonic() + self.leader_timeout
        told = False
        while not stop.is_set():
            left = missing()
            if not left:
                return True
            if self.clock.monotonic() >= end:
                self.failure = (f"robot {left[0]} did not come back for its scheduled "
                                f"{dict(back)[left[0]]} at t = {k * self.scn.dt:g} s (tick {k}) within "
                                f"{self.leader_timeout:g} s")
                return False
            if not told:
                told = True
                log.info("world: waiting for robot%s %s to come back (at tick %d)", "s" if len(left) > 1 else "",
                         ", ".join(map(str, left)), k)
                self._report(force=True)  # a supervisor acts on the world's tick (k - 1 now)
            self.wake.wait(0.05)
            self.wake.clear()
        return False

    def _publish_lost(self, k: int) -> None:
        """Lock-step without faults, before tick k's poses: the robots lost (their token gone) where they stopped,
        so that every robot, neighbour or not, takes them as static bodies (docs/faults.md)."""
        with self.lock:
            lost = [i for i in range(self.n) if not self.alive[i]]
        bodies = tuple(protocol.Body(i, float(self.q[i][0]), float(self.q[i][1]), self.scn.r, self.scn.R) for i in lost)
        self.bus.put(keys.world_bodies(self.fleet), protocol.encode(protocol.Bodies(t=self.t, seq=k, bodies=bodies)),
                     reliable=True)

    def _publish_bodies(self, k: int) -> None:
        # the run loop calls this under faults only: self.wf is set
        self.bus.put(keys.world_bodies(self.fleet),
                     protocol.encode(self.wf.bodies(k, self.q)), reliable=True)  # type: ignore[union-attr]

    def _check_wait_rule(self, t: float, before: np.ndarray, alive: np.ndarray | None = None) -> None:
        """Lock-step: count the pairs of live robots the agents' wait rule did not cover this tick.

        On pose_k agent i subscribes to the block around its cell at k and keeps the block around its
        cell at k-1, dropping the rest (Agent._move_cells). So while robots publish state_k it surely
        holds held(i, k) = block(c_i(k-1)) | (block(c_i(k-2)) & block(c_i(k))); the new cells race with
        state_k. It waits for j at k when it has j's state_(k-1) and j was within wait_reach (reach + 2L)
        at k-1; its law uses j when j is within reach at k. Flagged, for either robot of a pair: (a)
        within reach at k, but the wait at k was not sure (farther than wait_reach at k-1, or j's cell at
        k-1 outside held(i, k-1)); (b) within wait_reach at k-1 (so maybe awaited), but j's cell at k
        outside held(i, k). Neither can happen while no robot moves more than L in a tick; when one does,
        the run may differ from swarm sim. alive: the live robots at the step (default: now).

        Without faults the pairs are looked at only when some robot moved more than L in this step or the
        one before: otherwise neither (a) nor (b) can hold (docs/runtime.md, "Lock-step: why a distributed
        run equals swarm sim"), and the check would only cost the world's thread CPU (about 250 us a tick at
        N = 37, against about 30 for the shortcut)."""
        wf = self.wf
        alive = self.alive if alive is None else alive
        live = np.flatnonzero(alive if wf is None else [self.alive[i] and wf.running(i, self.k) for i in range(self.n)])
        side = self.scn.cell_side
        c0 = np.floor(before / side)  # cells at k-1
        if self._cells_hist is None:  # the start blocks are subscribed before tick 0
            self._cells_hist = (c0, c0)
        cm1, cm2 = self._cells_hist  # cells at k-2 and k-3
        self._cells_hist = (c0, cm1)
        q = np.array(self.q)[:, :2]
        d = q - before  # every robot's step, live or not (one more robot can only make the check look)
        short, was_short = float((d * d).sum(axis=1).max(initial=0.0)) <= self.step_bound ** 2, self._short_step
        self._short_step = short
        if live.size < 2 or wf is None and short and was_short:
            return
        now, was = q[live], before[live]
        c1, c0, cm1, cm2 = np.floor(now / side), c0[live], cm1[live], cm2[live]

        def inside(blocks_of, a, cell_of, b):  # cell_of[b] within the 3x3 block around blocks_of[a]
            return np.abs(cell_of[b] - blocks_of[a]).max(axis=1) <= 1

        def held(prev, older, new, a, cell_of, b):  # cell_of[b] surely subscribed by a: see above
            return inside(prev, a, cell_of, b) | (inside(older, a, cell_of, b) & inside(new, a, cell_of, b))

        i, j, _ = pairs_within(now[:, 0], now[:, 1], self.scn.reach)
        far = np.hypot(*(was[i] - was[j]).T) >= self.wait_reach
        unannounced = int(np.count_nonzero(far | ~held(cm1, cm2, c0, i, c0, j) | ~held(cm1, cm2, c0, j, c0, i)))
        i, j, _ = pairs_within(was[:, 0], was[:, 1], self.wait_reach)
        lost = int(np.count_nonzero(~held(c0, cm1, c1, i, c1, j) | ~held(c0, cm1, c1, j, c1, i)))
        if unannounced or lost:
            first = self.overruns == 0
            self.overruns += unannounced + lost
            if first or self.overruns // 1000 > (self.overruns - unannounced - lost) // 1000:
                log.warning("at t = %g s robots moved farther than the %.3f m a lock-step tick assumes (a third of "
                            "the cell margin): %d pairs came within reach unannounced, %d left the cells of a robot "
                            "waiting for them (%d so far). This run may differ from swarm sim; a smaller --dt "
                            "shortens the steps", t, self.step_bound, unannounced, lost, self.overruns)

    def _run_realtime(self, stop: threading.Event) -> bool:
        """Real time. Robot i's pose goes out once per control period at phase i/N of it (staggered,
        as unsynchronized localization would be: N robots do not all wake at the same instant and
        queue behind each other on a few cores); clock, snapshot, metrics sample and progress at
        the period boundaries.

        The loop wakes every fine step, and all its work is on this thread: it drains the commands
        (a bus inbox: zenoh's threads run no Python and never wait for this thread's GIL) and
        integrates each robot lazily, one exact arc from where it was to the instant it is needed
        (its pose, a new command, the period boundary). Arcs compose exactly for a held command,
        so this is the fine-step integration without the work of moving every robot every step."""
        scn, n, fine = self.scn, self.n, self.fine_dt
        period = scn.dt
        epoch = self.clock.time() + 0.2  # a little lead so every process hears the clock before t = 0
        self.epoch = epoch
        q, comp, cmd, tq = self.q, self.comp, self.cmd, [0.0] * n

        def advance(i: int, t: float) -> None:  # robot i one exact arc up to time t, with its held command
            if t > tq[i]:
                kinematics.step_pose(q[i], comp[i], cmd[i][0], cmd[i][1], t - tq[i])
                tq[i] = t

        # on the fine grid: the world's time only advances in fine steps, and an event between two
        # of them would have the loop wake, find nothing to do, and spin until the next step
        phase = [round(i * period / n / fine) * fine for i in range(n)]
        pose_seq = [0] * n  # poses sent to each robot (the pose's seq)
        slot = [0] * n  # the period of each robot's next pose: after a stall, late slots are skipped, not sent in a burst
        poses = sorted((phase[i], i) for i in range(n))  # (due time, robot): a heap
        t_pub = 0.0
        end_k = int(math.ceil(scn.duration / fine - 1e-9))  # integer steps: no drift in t
        fine_k = 0
        self.t = 0.0
        self._publish_clock_rt(epoch)
        watch_t = -math.inf
        absent_since: float | None = None
        while not stop.is_set():
            fine_k = max(fine_k, min(end_k, int(math.floor((self.clock.time() - epoch) * self.speed / fine + 1e-9))))
            t = self.t = round(fine_k * fine, 9)
            mono = self.clock.monotonic()
            self._follow_plans(t, advance)
            if self.fleet_ros2 is not None:
                self._take_ros2_commands(mono, t, advance)
            else:
                self._take_commands(t, mono, advance)
            if mono - watch_t >= period / self.speed:  # the watchdog, once a period (as a drive)
                watch_t = mono
                self._watchdog(mono, t, advance)
            if poses[0][0] <= t + 1e-9:
                sent = self._pose_sent  # this thread's only (_take_commands reads it)
                sent[t] = mono
                while (first := next(iter(sent))) < t - ROUND_TRIP_HISTORY_S:
                    del sent[first]
                while poses[0][0] <= t + 1e-9:
                    _, i = heapq.heappop(poses)
                    advance(i, t)
                    if self.fleet_ros2 is not None:
                        # q[i] is [x, y, theta]: mypy takes a list's star for every argument left
                        self.fleet_ros2.publish_odom(i, t, *q[i], *cmd[i])  # type: ignore[call-arg]
                    else:
                        self._publish_pose(i, t, pose_seq[i])
                    pose_seq[i] += 1
                    slot[i] = max(slot[i] + 1, int(math.floor((t - phase[i]) / period + 1e-9)) + 1)
                    heapq.heappush(poses, (slot[i] * period + phase[i], i))
            if t >= t_pub - 1e-9 or fine_k >= end_k:
                for i in range(n):
                    advance(i, t)
                for key, data in self._status_inbox.drain():
                    self.event(("status", key, data))
                if self.rtf is not None:
                    self._take_faultstats()
                seq = int(math.floor(t / period + 1e-9))  # the period (after a stall, the ones missed are skipped)
                if self._running and seq > self.k + 1:
                    self.samples_missed += seq - self.k - 1  # fell behind: those periods have no sample
                self.k = seq
                self._tell_events(t, seq, lambda te: te <= t + 1e-9)
                self._publish_clock_rt(epoch)
                self._publish_snapshot(t, seq)
                self._publish_bodies_rt(t, seq)
                self._sample(t)
                self._report()
                t_pub = (seq + 1) * period
                if not self._running and (self.alive.all() or t >= 1.0):
                    with self.lock:
                        self._running = True  # real time's start barrier: every robot there (or 1 s gone)
                what = self._absent()  # the leader or every robot away longer than leader_timeout ends the run
                if what is None:
                    absent_since = None
                elif absent_since is None:
                    absent_since = mono
                    log.warning("world: %s away at t = %g s", "the leader" if what == "leader" else "every robot", t)
                elif mono - absent_since > self.leader_timeout:
                    self.failure = (f"leader lost at t = {t:g} s" if what == "leader" else f"no robot alive at t = {t:g} s")
                    return False
            if fine_k >= end_k:
                return False
            left = epoch + (t + fine) / self.speed - self.clock.time()  # the next fine step (every event is on the grid)
            if left > 0:
                self.clock.wait(stop, left)
            else:
                fine_k += 1  # its time has come (the floor above can round to just below it: no spin on that)
        for i in range(n):
            advance(i, self.t)
        return True

    def _take_commands(self, t: float, mono: float, advance) -> None:
        """Real time: the commands that came since the last fine step, and their round trips (pose published ->
        command here). A command is executed from now until its `until` (absent: two periods from now), then
        braked (_follow_plans); one that comes after its until is refused as too late (counted, not bad), and one
        of a robot whose token is gone is not executed (it is a body on the floor until its token is back)."""
        for key, data in self._cmd_inbox.drain():
            i = self._cmd_ids.get(key)
            try:
                if i is None:
                    raise ProtocolError(f"not a robot of this world: {key!r}")
                c = protocol.decode(data, "cmd", None, self.limits)
            except ProtocolError as e:
                self.bad.reject(key, e)
                continue
            with self.lock:
                fresh = self.bad.verdict(key, self._after_return(i, self.w_cmd[i], c.t, c.seq),
                                         f"robot {i}'s command t or seq")
                alive = i not in self._gone
            if not fresh:
                continue
            sent = self._pose_sent.get(c.t)
            if sent is not None and len(self.round_trips) < 1_000_000:
                self.round_trips.append(mono - sent)
            self._command(i, t, mono, c.v, c.w, c.until, alive, advance, c.t)

    def _command(self, i: int, t: float, mono: float, v: float, w: float, until: float | None, alive: bool,
                 advance, ct: float = -1.0) -> None:
        """Real time: robot i's new command (v, w) valid until `until` (None: two periods from t), at time t; ct:
        the command's own t (its poses echo it once it acts)."""
        if until is None:
            until = t + 2.0 * self.scn.dt
        self._cmd_seen[i] = t  # it speaks: not one to list as silent (_publish_bodies_rt), even if this one is late
        if until < t:
            self.cmd_expired += 1
            return
        if not alive:
            self.bad.stale += 1  # a dead robot's command, late on the network: it stays where it stopped
            return
        self.cmd_time[i] = mono  # the watchdog's: a command came
        if t < self.hold_until[i]:  # listed as standing: it does not move before the listing's hold ends
            self._deferred[i] = (v, w, until, mono, ct)
            heapq.heappush(self._plan, (self.hold_until[i], i, self._gen[i], 0))
            return
        self._deferred.pop(i, None)
        advance(i, t)
        self._gen[i] += 1
        self.cmd[i] = self.cmd_new[i] = (v, w)
        self.until[i] = until
        self.cmd_t[i] = ct
        self.stopped[i] = False
        self.commanded[i] = True
        heapq.heappush(self._plan, (until, i, self._gen[i], 1))

    def _follow_plans(self, t: float, advance) -> None:
        """Real time: every change of a robot's speed due by t: a command that ran out brakes, a step of the ramp
        every _ramp_h (to 1 - k h / RAMP_S of its speed at the k-th: never faster than a linear ramp), then the
        robot stands; a command held by a listing is executed when the hold ends (if still valid); a robot whose
        token went stops at once."""
        if self._died:
            with self.lock:
                died, self._died = self._died, []
            for i in died:
                advance(i, t)
                self._gen[i] += 1
                self.cmd[i] = (0.0, 0.0)
                self.stopped[i] = True
                self._deferred.pop(i, None)
        plan = self._plan
        while plan and plan[0][0] <= t + 1e-9:
            te, i, gen, k = heapq.heappop(plan)
            if gen != self._gen[i]:
                continue
            if k == 0:
                held = self._deferred.pop(i, None)
                if held is not None:
                    v, w, until, mono, ct = held
                    self._command(i, te, mono, v, w, until, i not in self._gone, advance, ct)
                continue
            advance(i, te)
            f = max(0.0, 1.0 - k * self._ramp_h / RAMP_S)
            if k == 1:
                self.cmd_held += 1
            v, w = self.cmd_new[i]
            self.cmd[i] = (v * f, w * f)
            if f > 0.0:
                heapq.heappush(plan, (te + self._ramp_h, i, gen, k + 1))
            else:
                self.stopped[i] = True

    def _watchdog(self, mono: float, t: float, advance) -> None:
        """Real time, once a control period: a robot whose newest command is older than the watchdog (wall s, as a
        drive's) is stopped (a last resort: a command runs out long before)."""
        for i in range(self.n):
            if self.stopped[i] or mono - self.cmd_time[i] <= self.watchdog:
                continue
            advance(i, t)
            self._gen[i] += 1
            self.cmd[i] = (0.0, 0.0)
            self.stopped[i] = True
            if self.cmd_time[i] > -math.inf:
                self.watchdog_stops += 1

    def _publish_bodies_rt(self, t: float, seq: int) -> None:
        """Real time, each period: the robots that stand still and that nobody may hear (docs/runtime.md, "The
        safety invariant"): dead (token gone) or dead or hung by the schedule, or stopped after commanding (its
        commands ran out, or the watchdog) and silent for BODIES_SILENT_S (one whose commands keep coming, late,
        also keeps sending its states), where they are now, as lock-step's bodies message gives them. A robot
        that never heard such a robot's state (it was outside its cells then) knows it only from here. A listed
        robot does not move before the listing's t + BODIES_HOLD_S (the world holds its next command), so every
        robot may take it as a static body until then. Sent every period while it lists a robot, else every
        BODIES_EVERY_S (a gap longer than the window's t_span would jump the robots' windows on it)."""
        if not self._running:
            return
        q, rtf = self.q, self.rtf
        listed = tuple(i for i in range(self.n) if i in self._gone or (rtf is not None and rtf.away(i, t)) or
                       (self.stopped[i] and self.commanded[i] and i not in self._deferred and
                        t - self._cmd_seen[i] >= BODIES_SILENT_S))
        if not listed and not self._listed and t - self._listed_t < BODIES_EVERY_S:
            return
        for i in listed:
            self.hold_until[i] = t + BODIES_HOLD_S
        static = tuple(protocol.Body(i, float(q[i][0]), float(q[i][1]), self.scn.r, self.scn.R) for i in listed)
        self._listed, self._listed_t = listed, t
        # best effort, like the poses: the next one comes a period later, and a reliable put to a robot behind a
        # lossy or cut link blocks the router's thread, which then closes that robot's link
        self.bus.put(keys.world_bodies(self.fleet), protocol.encode(protocol.Bodies(t=t, seq=seq, bodies=static)))

    def held_back(self) -> float | None:
        """Real time: the share of the robots' commands their safety rule held back (slowed or stopped), the mean
        of what each robot said last; None before any said."""
        shares = list(self.held_by_robot.values())
        return sum(shares) / len(shares) if shares else None

    def _realtime_metrics(self) -> dict:
        """Real time's own metrics keys (docs/metrics.md)."""
        held = self.held_back()
        return {"held_back": None if held is None else round(held, 4), "cmd_expired": self.cmd_expired,
                "cmd_braked": self.cmd_held, "watchdog_stops": self.watchdog_stops}

    def _take_faultstats(self) -> None:
        """Real time under faults: the robots' fault counters that came (world.realtime_faults)."""
        for key, data in self._faults_inbox.drain():
            parsed = keys.parse(key)
            try:
                if parsed is None or parsed.kind != "faults" or parsed.id is None or parsed.id >= self.n:
                    raise ProtocolError(f"not a robot of this world: {key!r}")
                m = protocol.decode(data, "faultstats", None, self.limits)
            except ProtocolError as e:
                self.bad.reject(key, e)
                continue
            with self.lock:
                gen = self.token_gen[parsed.id]
            if not self.rtf.take(parsed.id, m, gen):  # type: ignore[union-attr]  # the loop calls this with self.rtf
                self.bad.stale += 1

    def _take_ros2_commands(self, mono: float, t: float, advance) -> None:
        """Real time, ROS 2 robots: the cmd_vel each robot got since the last fine step (in order)."""
        # the loop calls this with self.fleet_ros2 set
        for i, v, w in self.fleet_ros2.take_commands():  # type: ignore[union-attr]
            if not (abs(v) <= self.limits.v_max and abs(w) <= self.limits.w_max):
                self.bad.reject(self.fleet_ros2.cmd_keys[i],  # type: ignore[union-attr]
                                ProtocolError(f"cmd_vel ({v:g}, {w:g}) beyond the bounds"))
                continue
            with self.lock:
                alive = i not in self._gone
            self._command(i, t, mono, v, w, None, alive, advance)  # a base runs a cmd_vel two periods, then brakes

    def _publish_clock_rt(self, epoch: float) -> None:
        """Real time, each period: the clock (its epoch is all a robot needs of it), best effort (as the bodies)."""
        self.bus.put(keys.world_clock(self.fleet),
                     protocol.encode(Clock(t=self.t, seq=self.k, epoch=epoch, speed=self.speed)))



@dataclass(frozen=True)
class WorldOptions:
    """How `swarm world` runs a scenario (the command line's flags)."""

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


def run_world(bus, clock, scn: Scenario, opts: WorldOptions = WorldOptions(), stop: threading.Event | None = None,
              fleet: str = "default", started: float | None = None) -> tuple[dict, "World"]:
    """Run scenario `scn` on `bus`: serve, wait for every robot and the leader (NotReady after
    opts.start_timeout), run, close. Returns the metrics and the world (its trace)."""
    stop = stop or threading.Event()
    started = time.perf_counter() if started is None else started
    world = World(bus, scn, fleet, lockstep=opts.lockstep, speed=opts.speed, watchdog=opts.watchdog,
                  tick_timeout=opts.tick_timeout, trace=opts.trace, clock=clock, lost_timeout=opts.lost_timeout,
                  ros2=opts.ros2, process_faults=opts.process_faults)
    world.start()
    try:
        log.info("world: %d robots, %d obstacles, %s, waiting for robots and leader", scn.n, len(scn.obstacles),
                 "lockstep" if opts.lockstep else "realtime")
        try:
            world.wait_ready(opts.start_timeout, stop)
        except InterruptedError:
            pass
        if stop.is_set():
            metrics = world.referee.metrics(time.perf_counter() - started, True,
                                            "lockstep" if opts.lockstep else "realtime")
        else:
            settle_heap()
            log.info("world: every robot and the leader alive; run %s begins", world.run_id)
            metrics = world.run(stop, started)
    finally:
        world.close()
    return metrics, world

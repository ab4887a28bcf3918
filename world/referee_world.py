"""The referee without physics: a real fleet's run watched, recorded and reported like a simulated one.

    metrics, ref = run_referee(bus, clock, fleet, RefereeOptions(), stop, "lab")
    # which is: RefereeWorld(...).start() (queryables, the robots' states, tokens), .wait_ready()
    # (every robot and the leader alive, or NotReady naming the missing), .run() (the metrics), .close()

A real robot moves by itself: nothing here integrates anything. The referee serves what robots,
the leader and viewers ask a world for: world/run (the run's identity: the scenario's digest, as
given; the inventory's starts and limits belong to the fleet, not to the scenario),
world/config/<id> (robot i's slice with its real start and its limits tightened by the inventory)
and world/obstacles; it publishes the real-time clock (the epoch every process runs on),
world/snapshot and world/progress. The robots' poses are those their agents publish in their cell
states: odometry in the swarm's frame (swarm.drives.ros2). So the metrics of the contract
(docs/design.md) are computed by the same Referee (world.referee) as in simulation, from those
poses, and say so: `odometry_based: true`, and `max_pose_age_s`, the largest age of a live robot's
newest pose at a sample (its state's time against the sample's, on the swarm's clock: network
latency, up to a control period, and the clock offset between machines).

At every control period t_k = k dt of the real-time clock: take the states that came (each
robot's forward window, as every receiver keeps: swarm.proto.window), publish the clock, sample the
metrics with every live robot at its newest pose (a robot counts as live once its token is up and
its first state came; before that it stands at its start), publish the snapshot (v, w estimated
from the last two states; `stopped` when its newest state is older than the watchdog) and the
progress. The run ends at the scenario's duration, on stop, or when the leader (or every robot) is
away longer than lost_timeout (metrics `failure`). A robot whose token goes away during the run is
counted lost, as the simulated world counts it.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from world.ready import NotReady, wait_ready
from swarm.core import kinematics, runid
from swarm.core.clock import WALL, said_step
from swarm.core.safety import RAMP_S
from swarm.core.inventory import Fleet
from swarm.process import settle_heap
from swarm.net import presence
from swarm.proto import keys, protocol, window
from swarm.proto.protocol import Clock, Obstacle, Obstacles, ProtocolError, RobotSnap, Run, Snapshot
from world.estop import EstopLog
from world.referee import Referee, log_collisions

log = logging.getLogger("swarm.referee")

WATCHDOG_S = 0.5  # s: a robot whose newest state is older than this is shown stopped (and its windows span 2x)
LOST_TIMEOUT_S = 10.0
PROGRESS_PERIOD_S = 0.25  # wall seconds between progress messages
LEAD_S = 0.2  # the epoch is this far in the future when announced, so every process hears it before t = 0


@dataclass(frozen=True)
class RefereeOptions:
    speed: float = 1.0  # simulated seconds per wall second: 1 for real robots (a simulated fleet may run faster)
    watchdog: float = WATCHDOG_S
    lost_timeout: float = LOST_TIMEOUT_S
    start_timeout: float = 60.0
    trace: bool = False


class RefereeWorld:
    def __init__(self, bus, fleet: Fleet, name: str = "default", opts: RefereeOptions = RefereeOptions(),
                 clock=WALL, progress=None):
        self.bus, self.fleet, self.name, self.opts, self.clock = bus, fleet, keys.check_fleet(name), opts, clock
        self.on_progress = progress  # optional callable(protocol.Progress), for a local display
        scn = self.scn = fleet.scenario
        given = fleet.given
        self.n = n = scn.n
        self.run_id = runid.new_run_id(clock)
        self.digest = runid.digest(given)
        self._canonical = runid.canonical(given)
        self.limits = protocol.Limits.of(n, scn.reach)
        self.table = scn.leader.table()
        self.referee = Referee(scn)
        self.lock = threading.Lock()
        self.wake = threading.Event()
        self.alive = np.zeros(n, bool)  # liveliness tokens
        self.seen = np.zeros(n, bool)  # a first state came
        self.leader_alive = False
        self.q = np.array(scn.poses, float)  # each robot's newest pose (its start until its first state)
        self.q_t = np.full(n, -math.inf)  # the simulated time of that pose
        self.vw = np.zeros((n, 2))  # estimated from the last two states
        self.frozen = np.zeros(n, bool)
        self.stop = np.full(n, math.nan)  # what each robot's newest state announced it can still move (nan: nothing)
        self._listed: tuple[int, ...] = ()  # the robots the last bodies message listed, and its time
        self._listed_t = -math.inf
        self._spans = window.spans(scn.dt, opts.watchdog)
        self.w_state = [window.new(*self._spans) for _ in range(n)]
        self.w_status = [window.new(*self._spans) for _ in range(n)]
        self.bad = protocol.BadMessages(log)
        self.robot_bad = protocol.Claims()  # the robots' own counts of bad messages, bounded
        self.lost: set[int] = set()
        self.lost_events = 0
        self.failure: str | None = None
        self.max_pose_age = 0.0
        self.k = 0
        self.t = 0.0
        self.epoch: float | None = None
        self.trace: list[np.ndarray] | None = [] if opts.trace else None
        self._running = False
        self._strangers: set[int] = set()
        self._handles: list = []
        self._last_progress = -math.inf
        self._obstacles = protocol.encode(Obstacles(tuple(Obstacle(*map(float, o)) for o in scn.obstacles)))
        self._run_reply = protocol.encode(Run(run=self.run_id, digest=self.digest, robots=n, lockstep=False,
                                              scenario=self._canonical))

    # ------------------------------------------------------------------ wiring

    def start(self) -> None:
        f = self.name
        self._handles.append(self.bus.serve(keys.world_obstacles(f), lambda key: self._obstacles))
        self._handles.append(self.bus.serve(keys.world_config_any(f), self._config))
        self._handles.append(self.bus.serve(keys.world_run(f), lambda key: self._run_reply))
        self._states = self.bus.inbox(keys.cell_all(f), depth=16 * self.n + 64)
        self._statuses = self.bus.inbox(keys.robot_any(f, "status"), depth=8 * self.n + 64)
        self._handles += [self._states, self._statuses]
        self._handles.append(self.bus.watch_alive(keys.alive_any(f, "robot"), self._on_robot))
        self._handles.append(self.bus.watch_alive(keys.alive(f, "leader"), self._on_leader))
        self.bus.wanted(keys.world_snapshot(f))  # its matching status kept from now on (bus.wanted), before the first
        self._handles.append(presence.announce(self.bus, f, "world", run=lambda: self.run_id))
        self.estop = EstopLog(self.bus, f, now=lambda: (self.t, self.k), wall=self.clock.time)  # logged, told, counted (world.estop)
        self.estop.start()
        self._handles.append(self.estop)
        self.bus.put(keys.world_run(f), protocol.encode(Run(self.run_id, self.digest, self.n, False, "")),
                     reliable=True)

    estop: EstopLog | None = None  # the emergency stop's log (world.estop), once started

    def close(self) -> None:
        for h in self._handles[::-1]:
            h.close()
        self._handles.clear()

    def config(self, i: int) -> protocol.Config:
        """Robot i's slice: the scenario's, with its real start and its own (tighter) limits."""
        v_max, w_max = self.fleet.limits(i)
        return protocol.replace(runid.robot_config(self.scn, i, False, self.run_id, self.digest), v_max=v_max,
                                w_max=w_max)

    def _config(self, key: str) -> bytes | None:
        parsed = keys.parse(key)
        if parsed is None or parsed.kind != "config" or parsed.id is None or parsed.id >= self.n:
            return None
        return protocol.encode(self.config(parsed.id))

    def _on_robot(self, key: str, up: bool) -> None:
        parsed = keys.parse(key)
        if parsed is None or parsed.kind != "alive" or parsed.id is None:
            return
        i = parsed.id
        with self.lock:
            if i >= self.n:
                if up and i not in self._strangers:
                    self._strangers.add(i)
                    log.warning("robot %d is alive but not in this run (%d robots: 0..%d); it takes no part",
                                i, self.n, self.n - 1)
                return
            if up and i in self.lost and not self.alive[i] and self._running:
                log.warning("robot %d back at t = %g s (its liveliness token is here again)", i, self.t)
            if not up and self.alive[i] and self._running:
                self.lost.add(i)
                self.lost_events += 1
                log.warning("robot %d lost at t = %g s (its liveliness token is gone)", i, self.t)
            self.alive[i] = up
            if up:
                self.w_state[i].reset()
                self.w_status[i].reset()
        self.wake.set()

    def _on_leader(self, key: str, up: bool) -> None:
        with self.lock:
            self.leader_alive = up
        self.wake.set()

    def wait_ready(self, timeout_s: float, stop: threading.Event | None = None) -> None:
        """Wait until every robot and the leader are alive, timeout_s after the last one that came (world.ready);
        NotReady names the missing ones."""
        def missing() -> list[str]:
            with self.lock:
                return ([] if self.leader_alive else ["leader"]) + [f"robot {i}" for i in np.flatnonzero(~self.alive)]

        def wake(s: float) -> None:
            self.clock.wait(self.wake, s)
            self.wake.clear()
        wait_ready(missing, wake, self.clock.monotonic, timeout_s, stop)

    # ------------------------------------------------------------------ what came

    def _judge(self, w: window.Window, t: float, seq: int) -> str:
        """w.check(t, seq), but first by the referee's own clock: a t more than t_span ahead of its last period or
        behind it never counts toward re-anchoring the window (window.outside; docs/protocol.md, "Windows")."""
        span = self._spans[0]
        if not self.t - span <= t <= self.t + span:
            return window.outside(w, t, seq, t > self.t)
        return w.check(t, seq)

    def take_states(self) -> None:
        """The states (and statuses) that came since the last period: each robot's newest pose."""
        for key, data in self._states.drain():
            i = keys.cell_robot(key)
            try:
                if i is None:
                    raise ProtocolError(f"not a cell key: {key!r}")
                s = protocol.decode(data, "state", i, self.limits)
            except ProtocolError as e:
                self.bad.reject(key, e)
                continue
            with self.lock:
                if not self.bad.verdict(key, self._judge(self.w_state[i], s.t, s.seq), f"robot {i}'s state t or seq"):
                    continue
            dt = s.t - self.q_t[i]
            if self.seen[i] and dt > 0:
                x0, y0, th0 = self.q[i]
                self.vw[i] = ((s.x - x0) * math.cos(th0) + (s.y - y0) * math.sin(th0)) / dt, (s.theta - th0) / dt
            self.q[i] = (s.x, s.y, s.theta)
            self.q_t[i] = s.t
            self.frozen[i] = s.frozen
            self.stop[i] = math.nan if s.stop is None else s.stop
            self.seen[i] = True
        for key, data in self._statuses.drain():
            parsed = keys.parse(key)
            try:
                if parsed is None or parsed.kind != "status" or parsed.id is None or parsed.id >= self.n:
                    raise ProtocolError(f"not a robot of this run: {key!r}")
                st = protocol.decode(data, "status", None, self.limits)
            except ProtocolError as e:
                self.bad.reject(key, e)
                continue
            i = parsed.id
            with self.lock:
                if self.bad.verdict(key, self._judge(self.w_status[i], st.t, int(round(st.t / self.scn.dt))),
                                    "the status's t"):
                    self.robot_bad.take(i, st.bad, self.clock.monotonic())

    # ------------------------------------------------------------------ a period

    def sample(self, t: float, k: int) -> None:
        """Metrics, snapshot and progress at period k (time t [s])."""
        with self.lock:
            live = self.alive & self.seen
        age = t - self.q_t
        if live.any():
            self.max_pose_age = max(self.max_pose_age, float(age[live].max()))
        if self.trace is not None:
            self.trace.append(self.q.copy())
        xl, yl, thl, _v, _w = kinematics.leader_state(self.table, t)
        self.referee.sample(t, self.q, live, (xl, yl, thl))
        if self.referee.new_collisions:
            log_collisions(self.referee, t, log)
        key = keys.world_snapshot(self.name)
        if self.bus.wanted(key):
            stale = ~self.seen | (age > self.opts.watchdog)
            snap = Snapshot(t=t, seq=k, robots=tuple(
                RobotSnap(i, float(x), float(y), float(th), float(self.vw[i, 0]), float(self.vw[i, 1]),
                          bool(stale[i]), bool(self.alive[i]))
                for i, (x, y, th) in enumerate(self.q.tolist())))
            self.bus.put(key, protocol.encode(snap))
        self._publish_bodies(t, k, age)
        self._report()

    def _publish_bodies(self, t: float, k: int, age: np.ndarray) -> None:
        """Who lists a dead robot where there is no simulating world (docs/deploy.md): the referee, each period,
        lists every robot that stands silent (its token gone, or no state for the watchdog's time) at its newest
        state, its r grown by the `stop` that state announced (the most its commands could still move it; a
        sender that said nothing: the speed bound over the watchdog and one hold), so that every robot, near it or
        not, takes it as a static body. Every period while it lists one, else every BODIES_EVERY_S."""
        from world.world import BODIES_EVERY_S

        with self.lock:
            silent = self.seen & (~self.alive | (age > self.opts.watchdog))
        listed = tuple(int(i) for i in np.flatnonzero(silent))
        if not listed and not self._listed and t - self._listed_t < BODIES_EVERY_S:
            return
        V, scn = self.scn.speed_bound, self.scn
        bodies = []
        for i in listed:
            grow = self.stop[i] if math.isfinite(self.stop[i]) else V * (self.opts.watchdog + 2 * scn.dt + RAMP_S)
            bodies.append(protocol.Body(i, float(self.q[i, 0]), float(self.q[i, 1]), scn.r + grow, scn.R + grow))
        self._listed, self._listed_t = listed, t
        self.bus.put(keys.world_bodies(self.name), protocol.encode(protocol.Bodies(t=t, seq=k, bodies=tuple(bodies))))

    def progress(self) -> protocol.Progress:
        ref = self.referee
        conv = ref.converged_at()
        with self.lock:
            alive = int(self.alive.sum())
        return protocol.Progress(t=self.t, seq=self.k, duration=self.scn.duration, robots=self.n, alive=alive,
                                 converged=ref.converged_now, frozen=ref.frozen_now,
                                 min_distance=ref.min_rr if math.isfinite(ref.min_rr) else -1.0, misses=0,
                                 bad=self.bad_total(), collisions=ref.collisions, overruns=0,
                                 min_obstacle=ref.min_ro if math.isfinite(ref.min_ro) else -1.0,
                                 position_error=ref.pmax if ref.samples and ref.alive_now else -1.0,
                                 orientation_error=ref.emax if ref.samples and ref.alive_now else -1.0,
                                 converged_at=-1.0 if conv is None else conv,
                                 last_freeze=-1.0 if ref.last_frozen_t is None else ref.last_frozen_t)

    def bad_total(self) -> int:
        estop = self.estop  # its log of the emergency stop: its refusals too
        return self.bad.count + sum(self.robot_bad.values()) + (0 if estop is None else estop.bad.count)

    def _report(self, force: bool = False) -> None:
        now = self.clock.monotonic()
        if force or now - self._last_progress >= PROGRESS_PERIOD_S:
            self._last_progress = now
            p = self.progress()
            self.bus.put(keys.world_progress(self.name), protocol.encode(p))
            if self.on_progress is not None:
                self.on_progress(p)

    def _absent(self) -> str | None:
        with self.lock:
            if not self.leader_alive:
                return "leader"
            if not self.alive.any():
                return "robots"
        return None

    # ------------------------------------------------------------------ the run

    def run(self, stop: threading.Event | None = None, started: float | None = None) -> dict:
        """Referee the run to the scenario's duration (or stop, or a failure); returns the metrics."""
        stop = stop or threading.Event()
        started = time.perf_counter() if started is None else started
        run_started = time.perf_counter()
        self.clock.anchor()  # take up a step of the system clock made before this run
        interrupted = self._run(stop)
        said_step(self.clock, log, "referee", self.run_id)
        self._report(force=True)
        if self.failure:
            log.error("referee: the run ended early: %s", self.failure)
        with self.lock:
            alive_end = int(self.alive.sum())
            self._running = False
        if not (self.alive & self.seen).any():
            self.referee.alive_now = 0
            self.referee.good_since = None
        return self.referee.metrics(
            time.perf_counter() - started, interrupted, "realtime", cmd_misses=0, bad_messages=self.bad_total(),
            steps=self.k, robots_alive_at_end=alive_end, robots_lost=self.lost_events, lost_robots=sorted(self.lost),
            lost_robots_back=sorted(i for i in self.lost if self.alive[i]),
            run_wall_s=time.perf_counter() - run_started, failure=self.failure, run_id=self.run_id,
            scenario_digest=self.digest, stale_messages=self.bad.stale, odometry_based=True,
            max_pose_age_s=self.max_pose_age, referee_only=True,
            **(self.estop.metrics() if self.estop is not None else {}))

    def _run(self, stop: threading.Event) -> bool:
        """The loop of periods; True if stopped."""
        scn, dt, speed = self.scn, self.scn.dt, self.opts.speed
        epoch = self.epoch = self.clock.time() + LEAD_S
        end_k = int(math.ceil(scn.duration / dt - 1e-9))
        with self.lock:
            self._running = True
        self._publish_clock(0.0, 0, epoch)
        absent_since: float | None = None
        k = 0
        while True:
            left = epoch + k * dt / speed - self.clock.time()
            if left > 0 and self.clock.wait(stop, left):
                return True
            if stop.is_set():
                return True
            now_k = int(math.floor((self.clock.time() - epoch) * speed / dt + 1e-9))
            k = min(end_k, max(k, now_k))  # after a stall, the periods missed are skipped, not sampled in a burst
            self.k, self.t = k, round(k * dt, 9)
            self.take_states()
            self._publish_clock(self.t, k, epoch)
            self.sample(self.t, k)
            what = self._absent()
            mono = self.clock.monotonic()
            if what is None:
                absent_since = None
            elif absent_since is None:
                absent_since = mono
                log.warning("referee: %s away at t = %g s", "the leader" if what == "leader" else "every robot", self.t)
            elif mono - absent_since > self.opts.lost_timeout:
                self.failure = (f"leader lost at t = {self.t:g} s" if what == "leader"
                                else f"no robot alive at t = {self.t:g} s")
                return False
            if k >= end_k:
                return False
            k += 1

    def _publish_clock(self, t: float, k: int, epoch: float) -> None:
        self.bus.put(keys.world_clock(self.name),
                     protocol.encode(Clock(t=t, seq=k, epoch=epoch, speed=self.opts.speed)), reliable=True)


def run_referee(bus, clock, fleet: Fleet, opts: RefereeOptions = RefereeOptions(), stop: threading.Event | None = None,
                name: str = "default", started: float | None = None, progress=None) -> tuple[dict, RefereeWorld]:
    """Referee one real run of `fleet` on `bus`: serve, wait for every robot and the leader (NotReady after
    opts.start_timeout), run, close. Returns the metrics and the referee (its trace)."""
    stop = stop or threading.Event()
    started = time.perf_counter() if started is None else started
    ref = RefereeWorld(bus, fleet, name, opts, clock, progress)
    ref.start()
    try:
        log.info("referee: %d robots, %d obstacles, waiting for robots and leader", ref.n,
                 len(fleet.scenario.obstacles))
        try:
            ref.wait_ready(opts.start_timeout, stop)
        except InterruptedError:
            pass
        if stop.is_set():
            metrics = ref.referee.metrics(time.perf_counter() - started, True, "realtime", odometry_based=True,
                                          max_pose_age_s=None, referee_only=True)
        else:
            settle_heap()
            metrics = ref.run(stop, started)
    finally:
        ref.close()
    return metrics, ref

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

The class is put together by concern: what the world holds (world.state), what comes in (world.intake), what
it tells (world.publishing) and its two runs (world.lockstep_loop, world.realtime_loop); World wires them to the
bus and runs them.
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np

from world.ready import NotReady
from world.state import FINE_DT_S, LOST_TIMEOUT_S, TICK_TIMEOUT_S, WATCHDOG_S, WorldOptions
from world.publishing import PROGRESS_PERIOD_S
from world.lockstep_loop import LockstepLoop
from world.realtime_loop import BODIES_EVERY_S, BODIES_SILENT_S, ROUND_TRIP_HISTORY_S, RealtimeLoop
from swarm.net import presence
from swarm.proto import keys, protocol
from swarm.core import runid
from swarm.core.clock import said_step
from swarm.process import settle_heap
from swarm.proto.protocol import Run
from swarm.core.scenario import Scenario
from world.estop import EstopLog

__all__ = ["World", "WorldOptions", "run_world", "NotReady", "WATCHDOG_S", "TICK_TIMEOUT_S", "LOST_TIMEOUT_S",
           "FINE_DT_S", "PROGRESS_PERIOD_S", "BODIES_EVERY_S", "BODIES_SILENT_S", "ROUND_TRIP_HISTORY_S"]

log = logging.getLogger("swarm.world")


class World(LockstepLoop, RealtimeLoop):
    """The simulated world of the module's docstring; its state and __init__ are world.state's WorldState."""

    estop: EstopLog | None = None  # the emergency stop's log (world.estop), once started

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
        self._handles.append(self.bus.watch_alive(keys.alive(f, "leader"), lambda k, up: ev(("leader", k, up))))
        if self.lockstep:  # the start barrier: every robot's state_0 (unsubscribed once passed)
            self._prime = self.bus.subscribe(keys.cell_all(f), lambda k, b: ev(("state", k, b)))
        # start keeping the snapshot key's matching status now (bus.wanted: a publisher and its listener), so that
        # the viewers and recorders already subscribed are known by tick 0 (else the first snapshot would go unsent)
        self.bus.wanted(keys.world_snapshot(f))
        self._handles.append(presence.announce(self.bus, f, "world", run=lambda: self.run_id))
        self.estop = EstopLog(self.bus, f, now=lambda: (self.t, self.k), wall=self.clock.time)  # logged, told, counted (world.estop)
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
                     lost_robots_back=sorted(i for i in self.lost if self.alive[i]),
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

    def _latency(self) -> dict:
        if not self.round_trips:
            return {}
        rt = np.array(self.round_trips) * 1e3
        return {"round_trip_ms_median": float(np.median(rt)), "round_trip_ms_p99": float(np.percentile(rt, 99)),
                "round_trips": int(rt.size)}


def run_world(bus, clock, scn: Scenario, opts: WorldOptions = WorldOptions(), stop: threading.Event | None = None,
              fleet: str = "default", started: float | None = None, teller=None) -> tuple[dict, "World"]:
    """Run scenario `scn` on `bus`: serve, wait for every robot and the leader (NotReady after
    opts.start_timeout), run, close. Returns the metrics and the world (its trace). teller: where to tell each
    progress message besides the bus (swarm.launch.progress_pipe.Teller: the launcher that started this world),
    with the real-time epoch."""
    stop = stop or threading.Event()
    started = time.perf_counter() if started is None else started
    world = World(bus, scn, fleet, opts, clock=clock)
    if teller is not None:
        world.on_progress = lambda p: teller.progress(p, None if opts.lockstep else getattr(world, "epoch", None),
                                                      opts.speed)
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

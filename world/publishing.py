"""What the simulated world tells: the clock, poses and snapshot of a tick, the fault events as they happen,
the referee's sample of ground truth and the progress that sums it up."""

from __future__ import annotations

import logging
import math
from typing import cast

import numpy as np

from world.intake import Intake
from swarm.proto import keys, protocol
from swarm.core import faultgen as fg
from swarm.core import faults as fl
from swarm.core import kinematics
from swarm.proto.protocol import Clock, Pose, RobotSnap, Snapshot
from world.referee import log_collisions

log = logging.getLogger("swarm.world")

PROGRESS_PERIOD_S = 0.25  # wall seconds between progress messages


class Publishing(Intake):
    # ------------------------------------------------------------------ publishing

    def _publish_tick(self, t: float, seq: int, epoch: float = 0.0, poses: list[bytes] | None = None) -> None:
        """The clock of tick seq, then every robot's pose (poses: each robot's pose already encoded)."""
        f = self.fleet
        self.bus.put(keys.world_clock(f), protocol.encode(Clock(t=t, seq=seq, epoch=epoch, speed=self.speed)),
                     reliable=True)
        self._publish_poses(t, seq, poses)

    def _publish_poses(self, t: float, seq: int, poses: list[bytes] | None = None) -> None:
        # the snapshot first: it is best effort (a viewer must never hold the world back), and at the
        # head of the burst it finds the send queue empty instead of behind N reliable poses
        self._publish_snapshot(t, seq)
        if poses is not None:  # lock-step without faults, each encoded as its command came (world.lockstep_loop)
            put, pose_keys = self.bus.put, self._pose_keys
            for i, payload in enumerate(poses):
                put(pose_keys[i], payload, reliable=True)
            return
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
        estop = getattr(self, "estop", None)  # the world's log of the emergency stop: its refusals too
        return self.bad.count + sum(self.robot_bad.values()) + ros + (0 if estop is None else estop.bad.count)

    def _report(self, force: bool = False) -> None:
        now = self.clock.monotonic()
        if force or now - self._last_progress >= PROGRESS_PERIOD_S:
            self._last_progress = now
            p = self.progress()
            self.bus.put(keys.world_progress(self.fleet), protocol.encode(p))
            if self.on_progress is not None:
                self.on_progress(p)

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

    def held_back(self) -> float | None:
        """Real time: the share of the robots' commands their safety rule held back (slowed or stopped), the mean
        of what each robot said last; None before any said."""
        shares = list(self.held_by_robot.values())
        return sum(shares) / len(shares) if shares else None

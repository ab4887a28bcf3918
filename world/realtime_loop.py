"""The simulated world's real-time run (every process on its own clock): each robot's newest command held until
its `until`, then braked; lazy exact arcs on a fine time grid; staggered poses; the watchdog; the bodies message."""

from __future__ import annotations

import heapq
import logging
import math
import threading

from world.publishing import Publishing
from swarm.proto import keys, protocol
from swarm.core import kinematics
from swarm.proto.protocol import Clock, ProtocolError
from swarm.core.safety import BODIES_HOLD_S, RAMP_S

log = logging.getLogger("swarm.world")

BODIES_EVERY_S = 0.2  # real time: the bodies message goes out every period while it lists a robot, else this often
BODIES_SILENT_S = 0.25  # real time: a robot stopped after commanding is listed once no command came for this long
ROUND_TRIP_HISTORY_S = 5.0  # real time: poses remembered for round trips (simulated s; far past the watchdog)


class RealtimeLoop(Publishing):
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
                fresh = self.bad.verdict(key, self._after_return(i, self.w_cmd[i], c.t, c.seq, behind=True),
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

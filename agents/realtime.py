"""The real-time step of one robot.

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
from typing import TYPE_CHECKING, cast

from swarm.proto import keys, protocol
from swarm.core import kinematics, law
from swarm.proto import window
from swarm.proto.protocol import Cmd, ProtocolError, State
from swarm.net.bus import drainer
from agents.state import KEY_IDS_MAX, LISTEN_PERIODS, POSE_LATE_PERIODS, STATUS_PERIOD_S, WATCHDOG_S
from agents.rtsafety import SafeCommand

if TYPE_CHECKING:
    from swarm.drives.base import Drive

log = logging.getLogger("swarm.robot")


class Realtime(SafeCommand):
    """Real time: a step at every pose (or a late one without it), from the inboxes drained in one batch."""

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
            self._received += n
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
            w = self.w_state[j] = window.new(math.inf, 2**62)  # forward only (see _on_state)
        v = w.check(t, s.seq)
        if v != window.OK and not self.bad.verdict(key, v, f"robot {j}'s t or seq"):
            return
        self._received += 1
        self.table[j] = s
        self.rx[j] = (0.0 if now is None or now <= t else now - t, mono)
        self.away.discard(j)

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

    def pose_taken(self, mono: float) -> None:
        """Real time (the step's thread): a new pose was taken at monotonic time mono: the next one is due a period
        on (late_timer armed with it)."""
        self.last_pose_at = mono
        self._late_next = mono + POSE_LATE_PERIODS * self._period_wall()
        if self.late_timer is not None:
            self.late_timer.arm(self._late_next)

    def late_due(self) -> float | None:
        """Real time: the monotonic time at which a step without a new pose is due (None: none is; only with
        a periodic drive, and for WATCHDOG_S after the last pose: then the guard halts the drive anyway)."""
        if not self.periodic or self.last_pose_at is None or self.epoch is None or self._rt_belief is None:
            return None
        due = self._late_next
        return due if due - self.last_pose_at <= WATCHDOG_S else None

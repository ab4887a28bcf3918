"""A robot's links to the bus: the subscriptions of the 3x3 cells around it (moved as it moves, released
from the loop thread), the probes for neighbours unheard, and what it puts: its state on its cell key
(and, real time, the cells it left), its command, its status and fault counters.
"""

from __future__ import annotations

import logging
import math

from swarm.proto import keys, protocol
from swarm.core import law
from swarm.proto.protocol import Cmd, Status
from agents.state import DEPART_EVERY, DEPART_S, HINTS_PER_TICK, PROBE_S, STATUS_PERIOD_S, block
from agents.intake import Intake

log = logging.getLogger("swarm.robot")


class Links(Intake):
    """Subscriptions by cell, and the messages this robot puts."""

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
        it, the compiled loops built), else through _on_state_msg: the same rules either way."""
        if self._state_sink is None:
            return self.bus.subscribe(key, self._on_state_msg)
        return self.bus.subscribe_sink(key, self._state_sink)

    def _sink_error(self, key: str | None, e: BaseException) -> None:
        """The compiled sink's errors (a message that tripped a bug costs that message): counted and logged."""
        with self.lock:
            self.bad.reject(key or "?", RuntimeError(f"taking a state raised {type(e).__name__}: {e}"))

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

    def _publish_state(self, pose, seq: int) -> None:
        c = keys.cell_of(pose.x, pose.y, self.side)
        key = self._state_keys.get(c)
        if key is None:
            key = self._state_keys[c] = keys.cell(self.fleet, c[0], c[1], self.id)
        # the fields in State's order, encoded without building one (protocol.encoder)
        s = self._enc_state(self.id, pose.t, seq, pose.x, pose.y, pose.theta, self._r, self._R,
                            bool(self.mem[law.M_FROZEN]), self._rt_stop, self._rt_still)
        # lock-step: reliable (BLOCK). A state lost on the way costs its neighbours a wait_timeout and the run its
        # equality with swarm sim; zenoh's DROP loses messages when a queue is busy for a millisecond (a loaded
        # machine), not only when it is full.
        # Real time: best effort (a late state is worth less than the next one). Its own state is of no use to
        # this robot's cell inboxes (loopback off).
        self.bus.put(key, s, reliable=self.cfg.lockstep, loopback=False)
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

    def _publish(self, t: float, seq: int, v: float, w: float, ref: tuple, pose, estop_checked: bool = False) -> None:
        """Its command (v, w) of tick seq, and every STATUS_PERIOD_S its status; estop_checked: (v, w) is already zero
        if the emergency stop was engaged when it was computed (its pose ahead was predicted with it)."""
        if self.estopped is not None and not estop_checked:
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
                        neighbours=self.neighbours, stale=self.stale, bad=self.bad_count(),
                        held=None if self.cfg.lockstep else self.held / max(1, self.commanded))
            self.bus.put(self._status_key, protocol.encode(st))
            if self.counters is not None:
                self._report(t)

    def bad_count(self) -> int:
        """The bad messages this robot refused: its own and its drive's (a pose that did not decode: real time,
        where the drive takes the poses; a drive without a count has none to add)."""
        drive_bad = getattr(self.drive, "bad", None)
        return self.bad.count + int(getattr(drive_bad, "count", 0))

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

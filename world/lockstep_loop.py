"""The simulated world's lock-step run (the world owns the clock): the start barrier, then per tick the clock and
poses out, every live robot's command awaited, one exact arc each; under faults, membership by the schedule; and
the check of the agents' wait rule."""

from __future__ import annotations

import logging
import math
import threading
from typing import TYPE_CHECKING

import numpy as np

from world.publishing import Publishing
from swarm.proto import keys, protocol
from swarm.core import kinematics
from swarm.proto.protocol import Clock
from swarm.core.geometry import pairs_within
from swarm.core.faulttable import first_tick

if TYPE_CHECKING:
    from world.faultworld import WorldFaults

log = logging.getLogger("swarm.world")


class LockstepLoop(Publishing):
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
        taken = False  # the thread of the last tick's last command finished it and published this one
        try:
            for k in range(n_steps + 1):
                self.k, self.t = k, k * dt
                t = self.t
                if k > 0 and not taken:
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
                    self._inline_from = k if wf is None else -1  # its last command's thread may finish tick k
                    ups = self.leader_ups
                taken = False
                while True:
                    if stop.is_set():
                        return True
                    self._resend_clock()  # a leader that came back during this tick hears the clock at once
                    with self.lock:
                        # taken over by the thread of its last command (_take_over): done once the clock and poses
                        # of k + 1 are out
                        taken = self.k > k
                        if taken:
                            if not self._inline_busy:
                                later, self._inline_later = self._inline_later, None
                                if self.failure is not None:  # its poses did not go out (_publish_taken)
                                    return stop.is_set()
                                break
                            left, away = 0.5, False
                        else:
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
                                    log.warning("world: no command from robot%s %s for tick %d (t = %g s) within %g s; "
                                                "%s held (%d ticks with misses so far)", "s" if len(waiting) > 1 else "",
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
                if taken:  # stepped and published already: the next tick's bookkeeping
                    continue
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
            with self.lock:
                self._inline_from = -1  # no command's thread takes a tick over from now on
            end = self.clock.monotonic() + 5.0
            while self._inline_busy and self.clock.monotonic() < end:  # one is publishing: let it finish
                self.wake.wait(0.05)
                self.wake.clear()
            with self.lock:  # a step taken over that the run loop did not see (it stopped meanwhile)
                if later is None and self._inline_later is not None:
                    later, self._inline_later = self._inline_later, None
            if later is not None:
                self._check_wait_rule(*later)
            log.debug("world: %d of %d ticks finished on the thread of their last command", self.taken_over, self.k)
        return stop.is_set()

    # ------------------------------------------------------------------ the tick's last command finishes it

    def _step_next(self, i: int, c: protocol.Cmd) -> None:
        """Lock-step without faults, under the lock, as robot i's command of tick k is taken: its pose of tick k + 1
        (the run loop's step: the same function on the same bits) and that pose encoded, for _take_over."""
        q, comp = self.q[i][:], self.comp[i][:]
        kinematics.step_pose(q, comp, c.v, c.w, self.scn.dt)
        k1 = c.seq + 1
        payload = None  # a pose that is not finite: the run loop steps it again and ends the run (self.failure)
        if all(math.isfinite(a) for a in q):
            payload = protocol.encode(protocol.Pose(t=k1 * self.scn.dt, seq=k1, x=q[0], y=q[1], theta=q[2],
                                                    cmd=self.cmd_t[i]))
        self._next[i] = (c.seq, q, comp, payload)

    def _take_over(self) -> tuple[float, int, list[bytes]] | None:
        """Lock-step without faults, under the lock, on the thread of tick k's last awaited command: finish tick k
        here when the run loop would do nothing else (every robot and the leader alive, every robot's command of k
        in, tick k not the last): the step of every robot, then (t, k + 1, the poses) for _publish_taken. None
        otherwise: the run loop, woken, does it."""
        k = self._await
        if (k != self._inline_from or self._inline_busy or k >= self.scn.steps or not self.leader_alive or
                self._leader_back or not self.alive.all()):
            return None
        nxt, pending = self._next, self._pending
        if len(pending) != self.n or any(e is None or e[0] != k or e[3] is None for e in nxt):
            return None
        before = np.array(self.q)[:, :2]
        t = self.t
        for i, (_k, q, comp, _payload) in enumerate(nxt):
            self.cmd[i] = pending[i]
            self.cmd_time[i] = t
            self.stopped[i] = False
            self.q[i][:] = q
            self.comp[i][:] = comp
        self._pending = {}
        self._await = self._inline_from = -1
        self._inline_busy = True
        self.taken_over += 1
        self._inline_later = (t + self.scn.dt, before, self.alive.copy())
        self.k, self.t = k + 1, (k + 1) * self.scn.dt
        return self.t, self.k, [e[3] for e in nxt]

    def _publish_taken(self, t: float, k: int, poses: list[bytes]) -> None:
        """On the thread that took tick k - 1 over: clock k and the poses of k out, then the run loop wakes for tick
        k's bookkeeping (the metrics' sample, the progress, the wait rule's check of the step)."""
        try:
            self._publish_tick(t, k, poses=poses)
        except Exception as e:  # the run loop ends the run with it (on its own thread the error ends it too)
            with self.lock:
                self.failure = f"the clock and poses of tick {k} could not be published: {type(e).__name__}: {e}"
        finally:
            with self.lock:
                self._inline_busy = False
            self.wake.set()

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

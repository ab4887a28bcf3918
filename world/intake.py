"""What comes in to the simulated world: lock-step commands, and the liveliness of the robots and the leader (who
is there), each taken under the lock; real time drains its commands, statuses and fault counters itself
(world.realtime_loop)."""

from __future__ import annotations

import logging
import threading
from typing import Callable, cast

import numpy as np

from world.ready import wait_ready
from world.state import WorldState
from swarm.proto import keys, protocol, window
from swarm.core import faults as fl
from swarm.proto.protocol import ProtocolError

log = logging.getLogger("swarm.world")


class Intake(WorldState):
    _leader_back = False  # the leader's token came back during the run (lock-step: repeat the clock for it)
    leader_ups = 0  # times the leader's token appeared
    # lock-step without faults (world.lockstep_loop, "the tick's last command finishes it"): a robot's pose of the
    # next tick stepped as its command comes; the tick taken over by the thread of its last awaited command, and
    # its clock and poses published there
    _step_next: Callable[[int, protocol.Cmd], None]
    _take_over: Callable[[], tuple[float, int, list[bytes]] | None]
    _publish_taken: Callable[[float, int, list[bytes]], None]

    # ------------------------------------------------------------------ events

    def event(self, item) -> None:
        """A bus event, on the bus's thread: update under the lock; wake the run loop when the
        awaited tick's commands are complete (or a robot came or went)."""
        with self.lock:
            self._handle(item)
            due = item[0] in ("alive", "leader", "state") or (self._await >= 0 and not self._awaited)
        if due:
            self.wake.set()

    def _on_cmd(self, key: str, data: bytes) -> None:
        """Lock-step: a command, on the bus's thread. event(("cmd", key, data)) in few steps: 37 of these a
        tick run on zenoh's threads. The last awaited command ends the tick on its thread (world.lockstep_loop,
        _take_over) when nothing else is due, else wakes the run loop (_awaited: the run loop sets it from
        _missing() at each wake-up; a robot that came or went wakes it anyway)."""
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
            tick = self._take_over() if due else None
        if tick is not None:  # this thread finishes the tick: the next one's clock and poses out now
            self._publish_taken(*tick)
        elif due:
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
            if self.wf is None:
                self._step_next(i, c)
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
            if i in self.lost and not self.alive[i] and self._running:
                log.warning("robot %d back at t = %g s (its liveliness token is here again)", i, self.t)
        elif i in self.token_mark:
            self.lapsed.add(i)
        if not up and self.alive[i] and self._running:
            if self.wf is not None and not self.wf.running(i, self.k):  # a scheduled kill or hang: membership
                log.info("robot %d's token is gone at t = %g s (its process is %s by the fault schedule)", i,
                         self.t, "dead" if self.wf.dead(i, self.k) else "hung")  # follows the schedule
            elif self.rtf is not None and self.rtf.away(i, now := self._now_rt()):  # real time: as scheduled
                log.info("robot %d's token is gone at t = %g s (its process is %s by the fault schedule)", i,
                         now, fl.process_state(cast(fl.Faults, self.scn.faults), i, now))
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

    def _after_return(self, i: int, w: window.Window, t: float, seq: int, behind: bool = False) -> str:
        """w.check(t, seq) for robot i's message; but in real time under faults, a jump right after robot i's
        scheduled hang or kill ended is the schedule's gap, not a bad message: the window starts again there.
        (Its returning token resets the window too, but its first messages can come before the token does.)
        First, by this world's own clock: a t more than t_span ahead of its now (or, with `behind`, in real time,
        more than t_span behind it) is judged without counting toward re-anchoring the window (window.outside):
        no robot of this world can have sent it, and three of them would pin the window where a forger wants.
        Likewise one the window refuses for its seq alone (window.by_seq_alone), but for a process the schedule
        restarted (its counter starts again from 0)."""
        now = self._now_rt()
        span = self._spans[0]
        if t > now + span or (behind and not self.lockstep and t < now - span):
            return window.outside(w, t, seq, t > now)
        if window.by_seq_alone(w, t, seq):
            if self.rtf is not None and self.rtf.returned(i, now, span):  # a restarted process counts from 0
                w.reset()
                return w.check(t, seq)
            return window.outside(w, t, seq, seq > w.seq)
        v = w.check(t, seq)
        if v == window.JUMP and self.rtf is not None and self.rtf.returned(i, now, span):
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

    def _absent(self) -> str | None:
        """What the run cannot go on without, now: the leader, or every robot (None if both are here)."""
        with self.lock:
            if not self.leader_alive:
                return "leader"
            if self.n and not self.alive.any():
                return "robots"
        return None

"""A robot's messages as they come: the bus callbacks decode them outside the lock, check each sender's
window on t and seq under it, keep what they say, and kick the step when it is due. A bad message is
dropped and counted (protocol.BadMessages), never raised.
"""

from __future__ import annotations

import logging
import math

from swarm.proto import keys, protocol
from swarm.core import safety
from swarm.proto import window
from swarm.proto.protocol import ProtocolError, State
from agents.state import AgentState, HEAR_GAP_PERIODS

log = logging.getLogger("swarm.robot")


class Intake(AgentState):
    """The bus callbacks (on the bus's receiving thread) and what each message changes."""

    def _on_state_msg(self, key: str, data: bytes) -> None:
        """Lock-step: a neighbour's state (_receive for the message of every neighbour, every tick)."""
        if self.ended:
            return
        j = self._key_ids.get(key)
        try:
            if j is None:
                j = keys.cell_robot(key)
                if j is None:
                    raise ProtocolError(f"not a cell key: {key!r}")
                if len(self._key_ids) >= 4096:  # keys of robots long gone (or a stranger's): bounded
                    self._key_ids.clear()
                self._key_ids[key] = j
            s = self._dec_state(data, j)
        except ProtocolError as e:
            with self.lock:
                self.bad.reject(key, e)
            return
        with self.lock:
            waited = s.id in self.waiting
            self._on_state(s, key)
            # only the state that took the last awaited robot off can make the tick due (the compiled sink's
            # rule): anything else _due() reads woke the loop when it came (a pose, the reference, a token)
            due = waited and not self.waiting and self._due()
        if due:
            self.kick.set()

    def _on_pose_msg(self, key: str, data: bytes) -> None:
        self._receive(key, data, "pose", None, self._on_pose)

    def _on_ref_msg(self, key: str, data: bytes) -> None:
        self._receive(key, data, "ref", None, self._on_ref)

    def _on_clock_msg(self, key: str, data: bytes) -> None:
        self._receive(key, data, "clock", None, self._on_clock)

    def _on_bodies_msg(self, key: str, data: bytes) -> None:
        self._receive(key, data, "bodies", None, self._on_bodies)

    def _on_bodies(self, b: protocol.Bodies, key: str = "") -> None:
        """Lock-step under faults: the static bodies of tick b.seq (dead or stopped robots), every tick,
        and the robots returning at b.seq: their first pose is their state of that tick (taken as if it
        came from them: nobody waits for a robot that was away at b.seq - 1). Real time under faults: the
        robots standing still (dead, hung, stopped by the watchdog) where they are, each period: static
        bodies for bodies() until the next message (World._publish_bodies_rt)."""
        if not self.cfg.lockstep:
            if self.bad.verdict(key, self.w_bodies.check(b.t, b.seq), "the bodies' t or seq"):
                self.rt_static = {s.id: (s.x, s.y, s.r, s.R) for s in b.bodies if s.id != self.id and s.id < self.cfg.robots}
                self.rt_static_t = b.t
                if any(s.id == self.id for s in b.bodies):  # listed as standing: every robot takes it as static
                    self._still_until = max(self._still_until, b.t + safety.BODIES_HOLD_S)  # until then: so be it
            return
        if self.view is None:  # lock-step without faults: robots lost (token gone) where the world stopped them
            if self.bad.verdict(key, self.w_bodies.check(b.t, b.seq), "the bodies' t or seq"):
                for s in b.bodies:
                    if s.id != self.id and s.id < self.cfg.robots:
                        nb = self.table.get(s.id)
                        self.table[s.id] = State(id=s.id, t=b.t, seq=b.seq if nb is None else nb.seq, x=s.x, y=s.y,
                                                 theta=0.0 if nb is None else nb.theta, r=s.r, R=s.R, frozen=False)
                        self.dead.add(s.id)
                        self.waiting.discard(s.id)
            return
        if b.seq <= self.k_done or b.seq > self._next_tick():
            return  # an old tick's, or one too far ahead (the world publishes a tick's bodies just before its poses)
        self.static_by_seq[b.seq] = {s.id: (s.x, s.y, s.r, s.R) for s in b.bodies if s.id < self.cfg.robots}
        for s in b.returning:
            nb = self.table.get(s.id)
            if s.id != self.id and s.id < self.cfg.robots and (nb is None or nb.seq < b.seq):
                self.table[s.id] = State(id=s.id, t=b.t, seq=b.seq, x=s.x, y=s.y, theta=0.0, r=s.r, R=s.R,
                                         frozen=False)
                if b.seq == self.k_started:
                    self.waiting.discard(s.id)

    def _on_estop_msg(self, key: str, data: bytes) -> None:
        self._receive(key, data, "estop", None, self._on_estop)

    def _on_estop(self, e: protocol.Estop, key: str = "") -> None:
        """The emergency stop: latched by the guard (a real drive halts within a period: the guard's
        thread); a lock-step robot commands zero while it is engaged. Safety first: an engage that decodes
        is always obeyed, whatever its t and seq; a release only when it comes after every engage obeyed
        (window.StopOrder: judged on this machine's clock, so no forged engage far ahead pins the stop)."""
        act, verdict = self.estop_order.take(e.engaged, e.t, e.seq, self.clock.time())
        if verdict != window.OK:
            self.bad.verdict(key, verdict, "the emergency stop's t or seq")  # counted (an engage obeyed all the same)
        if not act:
            return
        self.estopped = e.reason or "engaged" if e.engaged else None
        if self.guard is not None:
            self.guard.estop(e.engaged, e.reason)

    def _on_alive_msg(self, key: str, up: bool) -> None:
        """A liveliness token came or went. A robot's: it is alive, or dead (a static body). A new token
        of the world, the leader or a robot restarts that sender's windows (a restarted process counts
        from 0 again)."""
        parsed = keys.parse(key)
        if parsed is None or parsed.kind != "alive" or parsed.id is None or self.ended:
            return
        if parsed.role in ("world", "leader") and parsed.id != 0:
            # not a world's or a leader's (they use id 0): taken, its going would halt this robot and its coming
            # reset the windows that sender's messages are judged by
            with self.lock:
                self.bad.reject(key, ProtocolError(f"a liveliness token of the {parsed.role} with id {parsed.id} "
                                                   "(the world and the leader use id 0)"))
            return
        with self.lock:
            if parsed.role == "robot":
                if parsed.id == self.id or parsed.id >= self.cfg.robots:
                    return
                self._on_alive(parsed.id, up)
                if up and parsed.id in self.w_state:
                    self.w_state[parsed.id].reset()
            elif parsed.role == "world":
                self.world_alive = up
                if self.guard is not None:
                    self.guard.world(up)  # real time: a robot that lost the world halts, as for a lost leader
                if up:
                    self.w_pose.reset()
                    self.w_clock.reset()
                    self.w_bodies.reset()  # real time: this robot was away (hung past its lease): the list moved on
                    self._world_ups += 1
                    if self.cfg.lockstep and self._world_ups > 1 and self.k_started >= 0:
                        # its session came back (it was stopped past its lease): the world went on without it and
                        # waits for its commands again; its next pose is of a tick ahead (_judge). (The world's own
                        # session coming back sets this too: the world's next pose, in step, ends it: _on_pose.)
                        self._rejoin = True
                    if self.view is not None and self._world_ups > 1:
                        # the world's token again: this robot's session came back (it was stopped past its lease):
                        # say so once its subscriptions are back (they were sent before this could arrive)
                        self._announce = True
                        self.wake.set()
            elif parsed.role == "leader":
                self.leader_alive = up
                if self.guard is not None:
                    self.guard.leader(up)
                if up:
                    self.w_ref.reset()
                    self.leader_ups += 1
            due = self._due()
        if due:
            self.kick.set()

    def _receive(self, key: str, data: bytes, kind: str, key_id: int | None, apply) -> None:
        if self.ended:
            return
        try:
            if kind == "state" and key_id is None:
                raise ProtocolError(f"not a cell key: {key!r}")
            dec = self._hot_dec.get(kind)  # the kinds of every tick: their generated decoders, at once
            msg = dec(data, key_id) if dec is not None else protocol.decode(data, kind, key_id, self.limits)
        except ProtocolError as e:
            with self.lock:
                self.bad.reject(key, e)
            return
        with self.lock:
            apply(msg, key)
            due = self._due()
        if due:
            self.kick.set()

    def _judge(self, w: window.Window, t: float, seq: int, lead: int) -> str | None:
        """The verdict on a message of the world or the leader (its pose, its clock, the reference): by its
        window, but first by what this robot itself knows of the time (lock-step: its tick, once it has one;
        real time: its now, once it has the run's epoch). Lock-step: a message of a tick more than `lead` past
        the next it can hear (_next_tick; 1 for a reference, put a tick ahead; 0 for a pose or a clock) is
        ahead, and None (passed by,
        uncounted, as a state) while its process is away by the fault schedule with no return before that
        tick; one of a tick it has done is behind; between the two, the window judges, restarted first if it
        was anchored where this robot cannot hear (a crafted message before its first tick). Real time: t
        more than t_span ahead of or behind its now, or refused for its seq alone (window.by_seq_alone). What
        is ahead or behind never counts toward re-anchoring the window (window.outside)."""
        if self.cfg.lockstep:
            if max(self.k_started, self.pose.seq if self.pose is not None else -1) < 0:
                return w.check(t, seq)  # no tick of its own yet: the first message anchors the window
            nxt = self._next_tick()
            if seq > nxt + lead:
                if self.view is not None and not self.view.active(nxt):
                    return None  # dead or hung by the schedule to its end: the messages pass it by
                if self._rejoin and w is not self.w_pose:
                    return None  # the world went on while it was away: passed by, uncounted, until it rejoins
                if self._rejoin and w.peek(t, seq) != window.FORGED:
                    # the world's first pose since this robot's session came back: it rejoins at that tick (the
                    # world waits for its commands again); only then, once, may a pose skip ticks
                    self._rejoin = False
                    self._rejoin_tick = seq
                    self.rejoined += 1
                    log.warning("robot %d: back after its session dropped; rejoins at tick %d (its last was %d)",
                                self.id, seq, self.k_done)
                    w.reset()
                    return w.check(t, seq)
                return window.outside(w, t, seq, True)
            if seq <= self.k_done:
                return window.outside(w, t, seq, False)
            if w.t is not None and not self.k_done < w.seq <= nxt + lead and w.peek(t, seq) in (window.JUMP, window.STALE):
                w.reset()
            return w.check(t, seq)
        now = self.sim_time(self.clock.time())
        span = self._spans[0]
        if now is not None and not now - span <= t <= now + span:
            return window.outside(w, t, seq, t > now)
        if window.by_seq_alone(w, t, seq):
            return window.outside(w, t, seq, seq > w.seq)
        return w.check(t, seq)

    def _on_clock(self, c: protocol.Clock, key: str = "") -> None:
        if c.epoch > 0 and self.epoch is None:
            off = window.epoch_offset(c, self.clock.time())
            if abs(off) > self._spans[0]:
                self.bad.reject(key, ProtocolError(window.epoch_refusal(off)))
                return
        v = self._judge(self.w_clock, c.t, c.seq, lead=0)
        if v is None or not self.bad.verdict(key, v, "the clock's t or seq"):
            return
        if self.cfg.lockstep and self.clock_seq < self._clock_needed <= c.seq and self.k_started >= 0:
            # the start barrier passed during the tick under way: the reference the leader puts on hearing this
            # clock gets a whole wait of its own (not what is left of the one that began at the pose)
            self.deadline = self.clock.monotonic() + self.wait_timeout
        self.clock_seq = max(self.clock_seq, c.seq)
        if c.epoch > 0 and self.epoch is None:  # real time: the run's epoch, once (a new run is a new agent)
            self.clock.anchor()  # take up a step of the system clock made before this run
            self.epoch, self.speed = c.epoch, c.speed

    def _on_state(self, s: State, key: str = "") -> None:
        """A neighbour's state. A robot hears a neighbour only while they share cells, so the gap between
        two of its states has no bound: its window is on this robot's own clock instead (lock-step: a
        state of a tick at most one ahead of this robot's; real time: t at most t_span ahead of now),
        and per sender only forward (older: stale; the same again: a duplicate)."""
        if s.id == self.id:  # it never hears its own (put with no loopback): another sender with its id
            self.bad.reject(key, ProtocolError(f"a state with this robot's own id {s.id} from elsewhere (an impostor)"))
            return
        if self.cfg.lockstep:
            nxt = self._next_tick()
            if self.view is not None and s.seq > nxt and not self.view.active(nxt):
                return  # its process is away by the fault schedule: states pass it by (no fault of the sender's)
            # without faults a neighbour's state may come a tick past the next one this robot computes: it sent
            # state_(k+1) with cmd_k before this robot's pose_k came (agents.lockstep, "States a tick ahead")
            ahead = s.seq > (nxt if self.view is not None else max(nxt, self._law_tick() + 1))
        else:
            now = self.sim_time(self.clock.time())
            ahead = now is not None and s.t > now + self._spans[0]
        if ahead and self._rejoin:
            return  # the swarm went on while this robot was away: passed by, uncounted, until it rejoins
        if ahead:
            self.bad.reject(key, ProtocolError(f"robot {s.id}'s state (t {s.t:g}, seq {s.seq}) is ahead of this "
                                               f"robot's clock beyond the window"))
            return
        w = self.w_state.get(s.id)
        if w is None:
            w = self.w_state[s.id] = window.new(math.inf, 2**62, dt=self._tick)  # forward only (see above)
        v = w.check(s.t, s.seq)
        if v != window.OK and not self.bad.verdict(key, v, f"robot {s.id}'s t or seq"):
            return
        self._received += 1
        if self.cfg.lockstep and self.view is None and s.seq > self._law_tick():
            # of the tick after the next one this robot computes (its sender sent it with its command: agents.lockstep,
            # "States a tick ahead"): kept aside until that tick is done (or passed by), whose law takes the
            # sender's state of it
            self.early[s.id] = s
            return
        self.table[s.id] = s
        if self.cfg.lockstep:
            if s.seq == self.k_started:
                self.waiting.discard(s.id)
        else:  # its age when it came: now on the swarm's clock minus its time (never below 0: clocks differ)
            self.rx[s.id] = (0.0 if now is None else max(0.0, now - s.t), self.clock.monotonic())
            self.away.discard(s.id)

    def _on_alive(self, j: int, up: bool) -> None:
        """Robot j's token came (up) or went (under the lock): a robot that goes is a static body for the law at
        its last state (real time: the safety rule keeps its motion bound until the world lists it: _rt_bodies);
        both are logged."""
        if up:
            if j in self.dead:
                log.info("robot %d: robot %d back (its liveliness token is here again)", self.id, j)
            self.dead.discard(j)
        else:
            if j not in self.dead:  # once the world is gone (the end of a run) robots leaving is no news
                log.log(logging.WARNING if self.world_alive else logging.INFO,
                        "robot %d: robot %d lost (its liveliness token is gone)", self.id, j)
            self.dead.add(j)
            if not (self.cfg.lockstep and self.k_started == 0 and self.k_done < 0):
                self.waiting.discard(j)  # at tick 0 it is waited for all the same (Lockstep._start_tick)

    def _on_ref(self, ref: protocol.Ref, key: str = "") -> None:
        v = self._judge(self.w_ref, ref.t, ref.seq, lead=1)
        if v is None:
            return
        if v == window.JUMP and self.counters is not None and self.w_ref.t is not None and \
                not window.by_seq_alone(self.w_ref, ref.t, ref.seq):
            lost = getattr(self.counters, "lost_t", (-math.inf,) * 4)[3]  # [faultgen.CLS_REF]
            if self.w_ref.t < lost < ref.t <= lost + self.w_ref.t_span:
                # real time under faults: its fault bus lost the references in between (a partition, a burst of
                # drops), and this one is within the window of the last it lost: the schedule's gap, not the
                # leader's jump (each was counted bad, 2 at a partition's end); a reference farther is refused
                self.w_ref.reset()
                v = self.w_ref.check(ref.t, ref.seq)
        if not self.bad.verdict(key, v, "the reference's t or seq"):
            return
        self.ref = ref
        self.refs_taken += 1
        if self.guard is not None:
            self.guard.ref(ref.t)
        if self.cfg.lockstep and ref.seq > self.k_done:
            self.refs[ref.seq] = ref

    def _on_pose(self, pose: protocol.Pose, key: str = "") -> None:
        if self.view is not None and self.view.schedule.fresh(self.id, pose.seq) is not None and \
                pose.seq > max(self.k_started, self.pose.seq if self.pose is not None else -1):
            self.w_pose.reset()  # it returns at pose.seq (restarted or resumed): its poses resume after a gap
        v = self._judge(self.w_pose, pose.t, pose.seq, lead=0)
        if v is None or not self.bad.verdict(key, v, "the pose's t or seq"):
            return
        self._rejoin = False  # a pose taken: in step with the world (rejoined, or it never fell behind)
        if not self.cfg.lockstep:
            mono = self.clock.monotonic()
            last = self.pose
            if last is None:
                self._heard_from = mono  # states before its first pose: nothing known of what it missed
            elif pose.seq != last.seq + 1 or mono - self._pose_mono > HEAR_GAP_PERIODS * self._period_wall():
                gaps = self._gaps  # a pose lost or late: states may have been missed in between
                if len(gaps) == gaps.maxlen:
                    self._heard_from = gaps[0][1]
                gaps.append((self._pose_mono, mono))
            self._pose_mono = mono
        self.pose = pose
        if self._state_sink is not None:
            self._state_sink.posed = pose.seq  # the sink's idea of this robot's next tick (_next_tick)

    def _missed(self, m0: float) -> float:
        """Real time: how long [simulated s] since monotonic time m0 this robot may have missed states (the gaps
        in its poses since); inf when that is not known (before its first pose, or further back than it keeps)."""
        if m0 < self._heard_from:
            return math.inf
        out = 0.0
        for a, b in reversed(self._gaps):
            if b <= m0:
                break
            out += b - (a if a > m0 else m0)
        return out * self.speed

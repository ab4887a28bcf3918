"""The lock-step tick protocol of one robot.

Lock-step tick k (the world owns the clock; docs/runtime.md):
  1. pose_k arrives: move the cell subscriptions (the old block is kept one more tick) and
     publish state_k on the cell key.
  2. Wait for state_k of every live robot whose state_(k-1) was within reach + 2L, where
     reach is the largest R (the law ignores bodies farther than that) and L = (side - reach) / 3
     is the largest step the protocol assumes (a robot that can matter at k, closer than reach,
     was within reach + 2L at k-1; one that was that close is still inside the cells subscribed
     at k-1, so its state_k is sure to arrive), for ref_k and for clock_k. At tick 0 nobody's previous
     state is known: it waits for the state_0 of every robot of the run that runs at 0 (its token gone or
     not, as the world's barrier does), heard in every cell (a subscription declared before its liveliness
     token, so before the world's pose_0 and anyone's state_0). clock_0, the world's start barrier, says
     only that every state_0 reached the world, not this robot: through a router, a neighbour's state_0
     may reach it after clock_0 and ref_0 (the run then differs from swarm sim from tick 1). After
     `wait_timeout` seconds it goes on with what it has and counts the missing as stale. A robot that
     moves more than L in a tick breaks the premise; the world then counts the pairs the rule could not
     cover (metrics `lockstep_overruns`): only then can a run differ from swarm sim.
  3. Compute cmd_k from the bodies closer than the cell side in ascending id order (the
     simulator's order: robots by id, then obstacles, then dead robots as static bodies; the
     law uses those closer than reach) and publish it.

States a tick ahead (`swarm robot`'s agents; without faults): once cmd_k is known, so is pose_(k+1), which the world
computes with kinematics.step_pose from pose_k and cmd_k as sent. The robot runs the same step on its own copy of the
pose and its compensations (from pose_0, where the world's compensations are 0 too: the same bits), moves its cells
to that pose, publishes cmd_k, then state_(k+1). So state_(k+1) is usually with its neighbours before pose_(k+1), and
a tick is one wake-up of each robot instead of two (its pose, then its last awaited state). As tick k + 1 starts, the
robot checks pose_(k+1) against its prediction: a world that did not apply cmd_k as sent (a miss: it held the last
command) makes them differ; the robot then says so (`mispredicted`), and from then on sends each state on its pose.
Its cells move before its command goes out, so they are in place before any neighbour's state_(k+1) can come (that
comes after the world's pose_k, which comes after this robot's cmd_(k-1)): step 2's argument holds as it stands.
A neighbour's state_(k+1) may then come while this robot is still at tick k, or before its pose_k: it is kept aside
(`early`) until tick k is done, so the law of k takes the neighbour's state_k. Robots that send on their pose (a
restarted process, another implementation of the key space, any run under faults) mix freely with those ahead.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from swarm.proto import keys, protocol
from swarm.core import kinematics, law
from swarm.proto.protocol import ProtocolError
from agents.bodies import Bodies

if TYPE_CHECKING:
    from agents.faultview import FaultView

log = logging.getLogger("swarm.robot")


class Lockstep(Bodies):
    """Lock-step: a tick starts at its pose, waits for the inputs the wait rule names, and commands."""

    def _lockstep_inputs(self) -> list:
        """Lock-step: (key, handler) of its pose, the reference and, under faults, the static bodies."""
        f = self.fleet
        out = [(keys.robot_pose(f, self.id), self._on_pose_msg), (keys.leader_ref(f), self._on_ref_msg)]
        if self.view is not None:
            out.append((keys.world_bodies(f), self._on_bodies_msg))
        return out

    def _resubscribe(self) -> None:
        """Lock-step under faults (loop thread): this robot's session came back after a stop past its lease.
        zenoh declares its subscriptions again by itself, but in no order one can count on; declared here
        once more, they are in place before the message that follows them on the same session (which tells
        the world this robot is back: World._await_returns)."""
        f = self.fleet
        for h in self._inputs:
            h.close()
        self._inputs = [self.bus.subscribe(key, fn) for key, fn in self._lockstep_inputs()]
        with self.lock:  # the world and the leader went on meanwhile: their next messages jump ahead
            self.w_pose.reset()
            self.w_ref.reset()
            self.w_clock.reset()
        for c in list(self._cells):
            self._cells.pop(c).close()
            self._cells[c] = self._subscribe_cell(keys.cell_any(f, *c))
        if self._all_sub is not None:
            self._listen_all(False)
            self._listen_all(True)

    def _listen_all(self, on: bool) -> None:
        """Lock-step (loop thread, or start()): hear every robot's state, in every cell, for tick 0 and, under
        faults, for a tick this robot returns at (restarted or resumed): it knows nobody's previous state then,
        so it waits for the state of every robot running then."""
        if on and self._all_sub is None:
            self._all_sub = self.bus.subscribe(keys.cell_all(self.fleet), self._on_any_state_msg)
        elif not on and self._all_sub is not None:
            self._all_sub.close()
            self._all_sub = None

    def _on_any_state_msg(self, key: str, data: bytes) -> None:
        """A state heard through _listen_all: kept only when it is of tick 0 before this robot has done it, or
        of a tick it returns at (its cells' subscriptions bring the same message through the windows of
        _on_state)."""
        if self.ended:
            return
        j = keys.cell_robot(key)
        try:
            if j is None:
                raise ProtocolError(f"not a cell key: {key!r}")
            s = protocol.decode(data, "state", j, self.limits)
        except ProtocolError as e:
            if not self._hears_cell(key):  # else its cell's subscription counts it (once)
                with self.lock:
                    self.bad.reject(key, e)
            return
        with self.lock:
            if s.id == self.id:
                return
            start = s.seq == 0 and self.k_done < 0
            if not start and (self.view is None or s.seq <= self.k_done or s.seq > self._next_tick() or
                              self.view.schedule.fresh(self.id, s.seq) is None):
                return  # not of tick 0 nor of a return tick of this robot (or too far ahead): its cells decide
            nb = self.table.get(s.id)
            if nb is None or nb.seq < s.seq:
                self.table[s.id] = s
            if s.seq == self.k_started:
                self.waiting.discard(s.id)
            due = self._due()
        if due:
            self.kick.set()

    def _hears_cell(self, key: str) -> bool:
        """A cell subscription of this robot's (`cell/<cx>/<cy>/*`, or one being released) may hear `key` too:
        its cell is one of them, or the key is no concrete cell (a put on a wildcard reaches them all)."""
        p = key.split("/")
        if len(p) < 4:
            return False
        cx, cy = p[-3], p[-2]
        try:
            c = (int(cx), int(cy))
        except ValueError:
            return "*" in cx or "*" in cy or "$" in cx or "$" in cy
        return c in self._cells or c in self._closing

    def _start_tick(self, pose) -> None:
        """Lock-step tick k starts (loop thread): publish state_k, decide whose state_k to wait for.
        Under faults the state is the robot's belief (its pose as it knows it: agents.faultview), and a
        robot whose process the schedule says is dead or hung at k does nothing."""
        k = pose.seq
        view = self.view
        if view is not None:
            b = view.start(k, (pose.x, pose.y, pose.theta), rejoin=k == self._rejoin_tick)
            if b is None:
                with self.lock:
                    self._idle = k
                    self.waiting = set()
                    self.k_started = k
                self._move_cells(pose.x, pose.y)  # where it stands (raw: for its subscriptions only)
                return
            pose = protocol.Pose(t=pose.t, seq=k, x=b[0], y=b[1], theta=b[2])
            self.belief = pose
        if not (self.ahead and self._as_predicted(pose, k)):
            self._move_cells(pose.x, pose.y)
        if self._sent_ahead != k:
            self._publish_state(pose, k)
        with self.lock:
            if self.early:  # of ticks up to k (tick k - 1 was left for this one, not done): this tick's now
                self._take_early(k)
            if view is not None:
                px, py, _ = view.previous(k)
            else:
                px, py = self.prev_xy if self.prev_xy is not None else (pose.x, pose.y)
            dead = self.dead
            reach2 = self._wait_reach * self._wait_reach
            wire = protocol._wire if view is None else None
            if wire is not None:  # the two loops below, compiled (swarm/proto/_wire_states.c)
                self.waiting = wire.wait_for(self.table, dead, k, px, py, reach2)
            else:
                self.waiting = set()
                for j in [j for j, nb in self.table.items() if nb.seq < k - 1 and j not in dead]:
                    del self.table[j]  # never used again (bounded state): a live robot counts only with state_k or state_(k-1)
                for j, nb in self.table.items():
                    if nb.seq == k - 1 and j not in dead and (px - nb.x) * (px - nb.x) + (py - nb.y) * (py - nb.y) < \
                            reach2 and (view is None or view.other_active(j, k)):  # under faults: nobody waits for a stopped robot
                        self.waiting.add(j)
            if k == self._rejoin_tick:
                self.waiting = set()  # it rejoins at k, listening (it holds still): nobody to wait for
            elif k == 0 or (view is not None and view.event is not None):
                # tick 0, or it returns at k (restarted or resumed): it knows nobody's state of k - 1, so it waits
                # for every robot running at k (heard in every cell: _listen_all), but those already here. At tick 0
                # the lost too, as the world's start barrier does (a robot serving several runs sees the token of
                # another's last run go, and its new one come, around pose_0): its state_0 came to the world if
                # clock_0 did
                self.waiting = {j for j in range(self.cfg.robots) if j != self.id and (k == 0 or j not in dead) and
                                (view is None or view.other_active(j, k)) and
                                not (j in self.table and self.table[j].seq == k)}
                if view is not None and view.event == "restart":
                    # a fresh controller (the same object when the process was not really killed: swarm world
                    # --process-faults played)
                    self.mem = self.control.fresh_memory()
            self.deadline = self.clock.monotonic() + self.wait_timeout
            self._leader_ups_seen = self.leader_ups
            self.k_started = k
            if self._state_sink is not None:  # the tick under way and whom it waits for, as the sink reads them
                self._state_sink.started, self._state_sink.waiting = k, self.waiting

    def _as_predicted(self, pose, k: int) -> bool:
        """States a tick ahead, as tick k starts: True if its cells are in place for pose_k (it moved them at the end
        of tick k - 1 to the pose it predicted, in the cell pose_k is in: moved again, the block it left would go a
        tick early). Unless pose_k is that pose bit for bit, the prediction starts again from pose_k: exact at tick 0
        (the world's compensations start at 0 too), and only for its cells after any other miss (the world's
        compensations are not known then); a state of k that went out ahead was wrong, and says so."""
        q = self._pred
        moved = self._pred_seq == k
        if moved and pose.x == q[0] and pose.y == q[1] and pose.theta == q[2]:
            return True
        in_place = moved and keys.cell_of(pose.x, pose.y, self.side) == keys.cell_of(q[0], q[1], self.side)
        if self._sent_ahead == k:
            self.mispredicted += 1
            if self.mispredicted <= 5 or self.mispredicted % 100 == 0:
                log.warning("robot %d: pose %d is not the one its state %d said ahead (%r, %r, %r against %r): the "
                            "world did not apply command %d as sent; states go out on poses from now on (%d so far)",
                            self.id, k, k, pose.x, pose.y, pose.theta, q, k - 1, self.mispredicted)
        self._pred, self._pred_c, self._pred_seq = [pose.x, pose.y, pose.theta], [0.0, 0.0, 0.0], k
        self._exact = k == 0
        return in_place

    def _step_ahead(self, k: int, v: float, w: float) -> protocol.Pose | None:
        """States a tick ahead (under the lock), once cmd_k = (v, w) is known: this robot's pose at tick k + 1 as the
        world will integrate it (kinematics.step_pose, the world's own step), or None without a prediction of k."""
        if self._pred_seq != k:
            return None
        q = self._pred
        kinematics.step_pose(q, self._pred_c, v, w, self.cfg.dt)
        self._pred_seq = k + 1
        return protocol.Pose(t=(k + 1) * self.cfg.dt, seq=k + 1, x=q[0], y=q[1], theta=q[2])

    def _take_early(self, upto: int) -> None:
        """Under the lock, as tick upto - 1 is done or tick upto starts: the states of ticks up to `upto` kept aside
        go to the table."""
        early = self.early
        if early:
            table = self.table
            for j in [j for j, s in early.items() if s.seq <= upto]:
                s = early.pop(j)
                nb = table.get(j)
                if nb is None or nb.seq < s.seq:
                    table[j] = s

    def _tick_done(self, k: int) -> None:
        """Tick k is done (under the lock): the states of k + 1 kept aside while it was under way go to the table."""
        self._take_early(k + 1)
        if self._state_sink is not None:
            self._state_sink.done = k

    def command(self, t: float, x: float, y: float, th: float, ref: tuple, seq: int) -> tuple[float, float]:
        """Lock-step: the law for this robot at time t with pose (x, y, th) and live reference ref = (xl, yl, thl,
        vl, wl), over the bodies of tick seq (the world applies a command for exactly dt: the governor's horizon
        is the period)."""
        nx, ny, nr, nR, nk, na, robots, stale = self.bodies(x, y, seq)
        xl, yl, thl, vl, wl = ref
        v, w = self._law(x, y, th, self.cfg.dx, self.cfg.dy, self.cfg.r, t, xl, yl, thl, vl, wl,
                                     nx, ny, nr, nR, nk, na, len(nx), self.mem, self.p)
        self.neighbours, self.stale = robots, stale
        self.stale_total += stale
        return v, w

    def _ticks(self) -> None:
        """Inline (Runner): every tick that is due now (tick_lockstep until it has nothing to do)."""
        while self.tick_lockstep():
            pass

    def tick_lockstep(self) -> bool:
        """Loop thread: start a new tick if its pose came, and compute it once its inputs are complete
        (or overdue). True if a command (or a skip) was issued."""
        if self._announce:
            self._announce = False
            if self.view is not None:
                # a process stopped before its first tick (hung at tick 0, or at the tick it was restarted for)
                # says so with tick 0 and its counters, all zero then (the world takes that as its word only)
                done = max(self.k_done, 0)
                # its next tick is its return: it hears every cell for it (stopped before its first tick, at 0 or
                # at the tick it was restarted for, it never reached the idle tick that subscribes it)
                with self.lock:
                    nxt = self._next_tick()
                self._listen_all((nxt == 0 and self.view.active(0)) or
                                 self.view.schedule.fresh(self.id, nxt) is not None)
                self._resubscribe()
                self.bus.put(self._faults_key, protocol.encode(protocol.FaultStats(
                    done * self.cfg.dt, done, *self.view.counters(),
                    frozen=bool(self.mem[law.M_FROZEN]))), reliable=True)
        self._end_start_listen()
        with self.lock:
            pose = self.pose
        if pose is None or pose.seq <= self.k_done:
            return False
        if pose.seq > self.k_started:
            self._start_tick(pose)
            if pose.seq > 0 and self.clock_seq >= 0:
                self.drop_clock()  # past the start barrier: the clock is not needed any more
        with self.lock:
            k = self.k_started
            newest: protocol.Pose = self.pose  # type: ignore[assignment]  # not None: a pose came (above)
            pose = newest if newest.seq == k else pose
            overdue = self.clock.monotonic() >= self.deadline
            if overdue and self.clock_seq < min(k, self._clock_needed) and self.world_alive:
                # the start barrier: clock_0 comes once every robot's state_0 is in the world, which may take it
                # longer than a tick's wait (a robot slow to start, pose_0 repeated to it every 0.25 s); going on
                # without it would go on without the reference too (the leader answers clock_0 with ref_0), and
                # the run would differ from swarm sim from its first tick. The world ends a barrier that fails.
                self.deadline = self.clock.monotonic() + self.wait_timeout
                return False
            if overdue and k not in self.refs and (not self.leader_alive or self.leader_ups != self._leader_ups_seen):
                # no reference because the leader is away, or came back during the tick and is catching up:
                # wait for it (the world holds the tick and ends the run if it does not come back)
                self._leader_ups_seen = self.leader_ups
                self.deadline = self.clock.monotonic() + self.wait_timeout
                return False
            if not self._inputs_complete(k) and not overdue:
                return False
            if overdue and not self._inputs_complete(k):
                self._overdue += 1
                if self._overdue <= 5 or self._overdue % 100 == 0:
                    what = ([f"the states of robots {sorted(self.waiting)[:8]}"] if self.waiting else []) + \
                        (["the reference"] if k not in self.refs else []) + \
                        (["the clock"] if self.clock_seq < min(k, self._clock_needed) else []) + \
                        (["the static bodies"] if self.view is not None and k not in self.static_by_seq else [])
                    log.warning("robot %d: tick %d goes on after %g s without %s (%d ticks so far)", self.id, k,
                                self.wait_timeout, ", ".join(what), self._overdue)
            ref = self.refs.get(k)
            ahead: protocol.Pose | None = None  # its pose at tick k + 1, predicted (states a tick ahead)
            self.k_done = k
            self.prev_xy = (pose.x, pose.y)
            for old in [s for s in self.refs if s <= k]:
                del self.refs[old]
            if self.static_by_seq:  # under faults only
                for old in [s for s in self.static_by_seq if s < k]:
                    del self.static_by_seq[old]
            if self.view is not None:
                if self._idle != k:
                    v, w, r = self._command_under_faults(k, ref)
                    belief: protocol.Pose = self.belief  # type: ignore[assignment]  # _start_tick set it: k is not idle
                    pose = belief
            elif k == self._rejoin_tick:
                # it rejoins at k (its session dropped and came back; the world went on): it knows nobody's state
                # of k - 1, so nobody was waited for, and holds still for this tick, as it stood while lost
                v = w = 0.0
                r = (ref.x, ref.y, ref.theta, ref.v, ref.w) if ref is not None else self._standing_ref(pose)
            elif ref is None:
                self.skipped += 1  # no reference for this tick (a restart mid-run): no command, the world holds
                log.warning("robot %d: no reference for tick %d, no command", self.id, k)
                self._tick_done(k)
                return True
            else:
                r = (ref.x, ref.y, ref.theta, ref.v, ref.w)
                v, w = self.command(pose.t, pose.x, pose.y, pose.theta, r, k)
                if self.estopped is not None:
                    v = w = 0.0  # the emergency stop holds every robot still (_publish): what the world applies
                if self.ahead:
                    ahead = self._step_ahead(k, v, w)
            self._tick_done(k)
        if self.view is not None:
            # before its command goes out (the world starts the next tick only once it has it): the next
            # tick this robot runs is a return tick, so it hears every cell from now on
            self._listen_all(self.view.returns_next(k))
            if self._idle == k:
                return True  # dead or hung at k: no state, no command (the world knows the schedule)
            c = self.view.counters()
            self.bus.put(self._faults_key, protocol.encode(protocol.FaultStats(
                pose.t, k, *c, frozen=bool(self.mem[law.M_FROZEN]))), reliable=True)
        if ahead is not None:  # its cells for tick k + 1 before its command: before anyone's state of k + 1 can come
            self._move_cells(ahead.x, ahead.y)
        self._publish(pose.t, k, v, w, r, pose, estop_checked=ahead is not None)
        if ahead is not None and self._exact:
            self._sent_ahead = k + 1
            self._publish_state(ahead, k + 1)
        self._end_start_listen()
        return True

    def _end_start_listen(self) -> None:
        """Without faults, once tick 0 is done: its cells bring every state it waits for from now on."""
        if self.view is None and self.k_done >= 0 and self._all_sub is not None:
            self._release("all", self._all_sub)
            self._all_sub = None

    def _command_under_faults(self, k: int, ref) -> tuple[float, float, tuple]:
        """Lock-step under faults (under the lock): the law given what the fault layer delivered; returns
        (v, w, the reference the law used, or the raw one for the status)."""
        view: FaultView = self.view  # type: ignore[assignment]  # tick_lockstep calls this under faults only
        view.reference(k, None if ref is None else (ref.x, ref.y, ref.theta, ref.v, ref.w))
        fresh = {j: (nb.x, nb.y) for j, nb in self.table.items() if nb.seq == k}
        for j in sorted(set(fresh) | set(view.tk) | set(view.ring_state)):
            if j != self.id:
                view.neighbour(k, j, fresh.get(j))
        listen, r = view.law_inputs(k)
        b: protocol.Pose = self.belief  # type: ignore[assignment]  # _start_tick set it: tick k is not idle
        if listen or r is None:
            v = w = 0.0  # listening (just restarted or resumed), or no reference yet: it holds still
            r = r or self._standing_ref(b)
        else:
            static = self.static_by_seq.get(k, {})
            nx, ny, nr, nR, nk, na = view.bodies(k, static, self.obstacles, self.cfg.r, self.cfg.R, law.KIND_ROBOT,
                                                 law.KIND_OBSTACLE, law.KIND_DEAD)
            xl, yl, thl, vl, wl = r
            v, w = self._law(b.x, b.y, b.theta, self.cfg.dx, self.cfg.dy, self.cfg.r, k * self.cfg.dt, xl, yl,
                                         thl, vl, wl, nx, ny, nr, nR, nk, na, len(nx), self.mem, self.p)
            self.neighbours = sum(1 for kind in nk if kind == law.KIND_ROBOT)
        view.commanded(k, v, w)
        return v, w, r

    def _standing_ref(self, pose) -> tuple[float, float, float, float, float]:
        """The reference of a robot holding still at pose without one (for its status): its slot where it stands."""
        return (pose.x - self.cfg.dx, pose.y - self.cfg.dy, pose.theta, 0.0, 0.0)

    def next_wakeup(self) -> float:
        """Seconds until tick_lockstep() may act by timeout (a bound for the loop's wait)."""
        with self.lock:
            if self.pose is None or self.pose.seq <= self.k_done:
                return 0.5
            if self.pose.seq > self.k_started:
                return 0.0
            return max(0.0, self.deadline - self.clock.monotonic())

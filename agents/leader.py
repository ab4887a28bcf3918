"""The leader: publishes the virtual leader's reference from the scenario's segments.

Lock-step: on world clock k it publishes ref_(k+1) (and any earlier ref it has not sent yet,
ref_0 and ref_1 on clock_0), one tick ahead so the reference is never on the critical path.
Real time: it publishes the reference every REF_PERIOD_S of simulated time on the world's
clock, and at the start of every segment. Between two messages an agent advances the reference
exactly along the leader's arc (v and w are constant within a segment), so a lower rate loses
nothing, and every robot takes one message a period less than at the control rate.
The reference at tick k is the leader's exact state at t_k = k dt (swarm.core.kinematics), the
same number the simulator uses.
"""

from __future__ import annotations

import logging
import queue
import threading

from swarm.net import presence
from swarm.proto import keys, protocol, window
from swarm.core import kinematics
from swarm.core.clock import WALL, said_step
from swarm.proto.protocol import ProtocolError, Ref

log = logging.getLogger("swarm.leader")

WATCHDOG_S = 0.5  # the windows on the clock's t and seq cover twice the watchdog, at least 2 s
_WORLD_BACK = "world token"  # an inbox item: the world's liveliness token is new
_CLOCK0 = protocol.encode(protocol.Clock(t=0.0, seq=0, epoch=0.0, speed=1.0))
REF_PERIOD_S = 0.1  # real time: simulated seconds between references (plus one at every segment start)


class Leader:
    def __init__(self, bus, table, dt: float, fleet: str = "default", lockstep: bool = True, rate_hz: float | None = None,
                 clock=WALL, run_id: str = ""):
        self.bus, self.table, self.dt, self.fleet, self.lockstep = bus, table, dt, fleet, lockstep
        self.run_id = run_id  # the run it serves, for `swarm ps` ("": none named)
        self.clock = clock
        self.period = 1.0 / rate_hz if rate_hz else REF_PERIOD_S  # simulated seconds between real-time refs
        self.switches = [float(t0) for t0 in table[1:, kinematics.SEG_T0]]  # segment starts after the first
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        self.next_seq = 0
        self.bad = protocol.BadMessages(log)
        self.epoch: float | None = None
        self.speed = 1.0
        self.sent = 0
        self.w_clock = window.new(*window.spans(dt, WATCHDOG_S), dt=dt if lockstep else 0.0)  # the world's clock:
        # forward, within a window; lock-step: its t is its tick's, seq x dt
        self.ended = False  # the run is over (a new one began): run() returns
        self._handles: list = []

    def start(self) -> None:
        self._handles.append(self.bus.subscribe(keys.world_clock(self.fleet),
                                                lambda k, b: self.inbox.put((k, b))))
        self._handles.append(self.bus.watch_alive(keys.alive(self.fleet, "world"),
                                                  lambda k, up: self.inbox.put((_WORLD_BACK, _CLOCK0)) if up else None))
        self._handles.append(presence.announce(self.bus, self.fleet, "leader", run=lambda: self.run_id))

    def close(self) -> None:
        for h in self._handles[::-1]:
            h.close()
        self._handles.clear()

    def publish(self, t: float, seq: int) -> None:
        x, y, th, v, w = kinematics.leader_state(self.table, t)
        # lock-step: reliable (a robot waits for the reference of its tick); real time: best effort, like the
        # poses (a robot extrapolates a missing one, and a reliable put to a robot behind a silent network cut
        # would block the router's forwarding to everyone: docs/runtime.md)
        self.bus.put(keys.leader_ref(self.fleet), protocol.encode(Ref(t=t, seq=seq, x=x, y=y, theta=th, v=v, w=w)),
                     reliable=self.lockstep)
        self.sent += 1

    def on_clock(self, key: str, data: bytes) -> None:
        try:
            c = protocol.decode(data, "clock")
        except ProtocolError as e:
            self.bad.reject(key, e)
            return
        if key == _WORLD_BACK:  # the world's token is new (a restarted world): its clock counts afresh
            self.w_clock.reset()
            return
        w = self.w_clock
        if not self.lockstep and c.epoch > 0 and self.epoch is None:
            off = window.epoch_offset(c, self.clock.time())
            if abs(off) > w.t_span:
                self.bad.reject(key, ProtocolError(window.epoch_refusal(off)))
                return
        if self.lockstep and w.t is not None and w.peek(c.t, c.seq) in (window.JUMP, window.STALE):
            # every clock of the world comes (reliable), so a jump is a forger's: one that counted toward
            # re-anchoring would have this leader publish a reference for every tick up to it (window.outside)
            v = window.outside(w, c.t, c.seq, c.seq > self.next_seq)
        else:
            v = w.check(c.t, c.seq)
        if not self.bad.verdict(key, v, "the clock's t or seq"):
            return
        if self.lockstep:
            if self.next_seq < c.seq:  # started (or restarted) mid-run: catch up from now
                self.next_seq = c.seq
            while self.next_seq <= c.seq + 1:
                self.publish(self.next_seq * self.dt, self.next_seq)
                self.next_seq += 1
        elif c.epoch > 0 and self.epoch is None:  # the run's epoch, once (a new run is a new leader)
            self.clock.anchor()  # take up a step of the system clock made before this run
            self.epoch, self.speed = c.epoch, c.speed

    def run(self, stop: threading.Event) -> None:
        while not stop.is_set() and not self.ended:
            if self.lockstep or self.epoch is None:
                try:
                    self.on_clock(*self.inbox.get(timeout=0.2))
                except queue.Empty:
                    pass
                continue
            # real time: publish every period of simulated time, on the world's clock
            now = self.clock.time()
            t = (now - self.epoch) * self.speed
            self.publish(t, self.next_seq)
            self.next_seq += 1
            t_next = min([(t // self.period + 1) * self.period] + [s for s in self.switches if s > t])
            wake = self.epoch + t_next / self.speed
            while not stop.is_set() and not self.ended:
                left = wake - self.clock.time()
                if left <= 0:
                    break
                try:
                    self.on_clock(*self.inbox.get(timeout=left))
                except queue.Empty:
                    break


def run_leader(bus, clock, scn, fleet: str = "default", lockstep: bool | None = None,
               stop: threading.Event | None = None, start_timeout: float = 60.0, once: bool = False) -> list[Leader]:
    """Publish scenario `scn`'s reference on `bus` for every run the world announces, until `stop` is
    set: a fresh leader per run (sequence numbers and clock from zero). A run of another scenario is
    refused (RunRefused, naming the first difference). lockstep: None follows the run's mode.
    Returns the leaders of the runs served (their counters)."""
    from agents.follow import RunFollower, check_run
    from swarm.core import runid

    stop = stop or threading.Event()
    current: list[Leader] = []

    def on_new(run) -> None:  # bus thread: the leader of the run under way stops
        for lead in list(current):
            lead.ended = True

    runs = RunFollower(bus, fleet, on_new)
    mine = runid.canonical(scn)
    served: list[Leader] = []
    try:
        run = runs.current(start_timeout, stop, me=("leader", 0))
        while not stop.is_set():
            if not run.scenario:
                run = runs.complete(run, start_timeout, stop)
            check_run(run, mine)
            mode = run.lockstep if lockstep is None else lockstep
            if mode != run.lockstep:
                log.warning("leader: --mode says %s but run %s is %s; following the run", "lockstep" if mode else
                            "realtime", run.run, "lock-step" if run.lockstep else "real time")
                mode = run.lockstep
            lead = Leader(bus, scn.leader.table(), scn.dt, fleet, lockstep=mode, clock=clock, run_id=run.run)
            current[:] = [lead]
            if runs.latest is not None and runs.latest.run != run.run:
                lead.ended = True
            log.info("leader: run %s begins (%s, %d robots)", run.run, "lock-step" if mode else "real time", run.robots)
            lead.start()
            try:
                lead.run(stop)
            finally:
                lead.close()
                current.clear()
            if not mode:
                said_step(clock, log, "leader", run.run)
            b = lead.bad
            log.info("leader: run %s %s: %d references sent; clock messages refused %d, stale %d, duplicated %d",
                     run.run, "ended" if lead.ended else "stopped", lead.sent, b.count, b.stale, b.duplicates)
            served.append(lead)
            if once:
                break
            nxt = runs.next(after=run.run, stop=stop)
            if nxt is None:
                break
            run = nxt
    finally:
        runs.close()
    return served

"""The fault-injecting bus: a Bus that applies the run's faults to what its process receives (real time).

    fbus = FaultBus(bus, table, me=3, dt=0.02, speed=2.0)    # table: swarm.core.faulttable.FaultTable
    agent = Agent(fbus, ...)                                  # everything else goes through unchanged
    fbus.dropped, fbus.delayed                                # counters by class (faultgen.CLS_* order)
    fbus.detach()                                             # its timer stops; the wrapped bus stays open

It wraps the receiving side of a process's bus (swarm.net.bus, the same interface). Every incoming
message on a key it knows is one message on one link of the fault model (docs/faults.md, The model):

    robot/<i>/pose         class pose, link (WORLD, i)
    leader/ref             class ref, link (LEADER, me)
    cell/<cx>/<cy>/<j>     class state, link (j, me)     (j != me)
    robot/<i>/cmd          class cmd, link (i, WORLD)

and is decided with the shared model, `FaultTable.link(cls, sender, receiver).decide(k, t)`, with k the
sender's seq and t the message's t (its simulated send time), so a partition cuts exactly the links
that decide says. A lost message is never delivered (counted in `dropped`); a message late by d control
periods is held d x dt / speed wall seconds from the moment this process takes it from the network
(counted in `delayed`), then delivered in order of its due time: with jitter, messages reorder. A
payload that does not decode, a key that is not one of these, or an id outside the scenario passes
through unchanged (the receiver's own code refuses it and counts it as bad: docs/protocol.md).

The three ways of receiving keep their meaning:
- subscribe / subscribe_raw: the handler runs on the bus's thread for a message delivered at once, and
  on this bus's timer thread for a held one (handlers already take a lock: they run on zenoh's threads);
- inbox: drain() returns the messages delivered since (held ones whose time came first, by due time,
  then the new ones in arrival order); wait() blocks until one is delivered: a held message wakes it
  when it falls due (the wrapped inbox's wake(), sent by the timer). A wait() may return [] (a message
  that came and was lost, or a wake-up), as the Bus interface allows;
- everything else (put, query, tokens, liveliness, queryables) is the wrapped bus's, untouched.

Nothing else in the project knows about faults: a process that runs under them is handed this bus
instead of its own, and its law never sees a lost message.

Bounds: at most HELD_MAX messages are held per inbox or subscription (beyond, the one due first is
delivered late rather than held more: `overflow`); a decision is skipped, and the message passed
through undecided (`undecided`), when the burst chain of a drop rule would need more than
MAX_CHAIN_STEPS steps to reach its seq (a hostile seq of 2^53, or a link first heard beyond an hour
of 50 Hz messages): a decision costs a few microseconds otherwise.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

from swarm.core import faultgen as fg
from swarm.core.clock import WALL
from swarm.net.bus import Closable, guarded
from swarm.proto import keys, protocol
from swarm.proto.protocol import ProtocolError

if TYPE_CHECKING:
    from typing import Literal

log = logging.getLogger("swarm.faultbus")

HELD_MAX = 4096  # messages held at once per inbox or subscription
MAX_CHAIN_STEPS = 200_000  # burst-chain steps one decision may take (pure Python: about 0.2 s at most)
CLASS_NAMES = ("state", "pose", "cmd", "ref")  # faultgen.CLS_* order
_KIND: dict[int, Literal["state", "pose", "cmd", "ref"]] = {
    fg.CLS_STATE: "state", fg.CLS_POSE: "pose", fg.CLS_CMD: "cmd", fg.CLS_REF: "ref"}


def intersects(a: str, b: str) -> bool:
    """Whether two zenoh key expressions (with * and **) can match a common key."""
    x, y = a.split("/"), b.split("/")

    def go(i: int, j: int) -> bool:
        if i == len(x) and j == len(y):
            return True
        if i < len(x) and x[i] == "**":
            return go(i + 1, j) or (j < len(y) and go(i, j + 1))
        if j < len(y) and y[j] == "**":
            return go(i, j + 1) or (i < len(x) and go(i + 1, j))
        if i == len(x) or j == len(y):
            return False
        return (x[i] == y[j] or x[i] == "*" or y[j] == "*") and go(i + 1, j + 1)

    return go(0, 0)


class FaultBus:
    """A Bus whose incoming messages go through the run's fault model (see the module's docstring).

    table: swarm.core.faulttable.FaultTable of the run; me: this process's id on links (a robot's id, or
    faultgen.WORLD for the world); dt: the control period [s]; speed: simulated seconds per wall second,
    a number or a function returning it (a robot learns it from the world's clock); clock: its
    monotonic() times the holds; timer: deliver held messages on a thread of its own when they fall due
    (False: only pump(), drain() and wait() deliver them: for tests on a fake clock)."""

    def __init__(self, inner, table, me: int, dt: float, fleet: str = "default", speed: float | Callable = 1.0,
                 clock=WALL, timer: bool = True) -> None:
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt!r}")
        self.inner, self.table, self.me, self.dt, self.clock = inner, table, me, float(dt), clock
        self.fleet = keys.check_fleet(fleet)
        self._speed = speed if callable(speed) else (lambda s=float(speed): s)
        self.errors = getattr(inner, "errors", None) or protocol.BadMessages(log)
        self.dropped = [0, 0, 0, 0]  # by class, faultgen.CLS_* order
        self.delayed = [0, 0, 0, 0]
        # by class, the t of the newest message this bus lost (pose, cmd, ref: one sender each): a receiver's
        # window takes a gap it explains (after a partition or a burst of drops) as the schedule's, not a jump
        self.lost_t = [-math.inf] * 4
        self.undecided = 0  # messages passed through without a decision (MAX_CHAIN_STEPS)
        self.overflow = 0  # held messages delivered early because HELD_MAX were held
        self._links: dict[tuple[int, int, int], object] = {}
        self._lock = threading.Lock()  # counters, links, held messages, the timer's heap
        self._timer = _Timer(clock, threaded=timer)
        self._prefix = keys.base(self.fleet) + "/"
        self._detached = False

    # ------------------------------------------------------------------ the model

    def classify(self, key: str) -> tuple[int, int, int] | None:
        """(class, sender, receiver) of a message on `key`, or None when it is no link of this process."""
        if not key.startswith(self._prefix):
            return None
        p = keys.parse(key)
        if p is None:
            return None
        n = self.table.robots
        if p.kind == "pose" and p.id is not None and p.id < n:
            return fg.CLS_POSE, fg.WORLD, p.id
        if p.kind == "cmd" and p.id is not None and p.id < n:
            return fg.CLS_CMD, p.id, fg.WORLD
        if self.me < 0:
            return None
        if p.kind == "ref":
            return fg.CLS_REF, fg.LEADER, self.me
        if p.kind == "cell" and p.id is not None and p.id < n and p.id != self.me:
            return fg.CLS_STATE, p.id, self.me
        return None

    def _may_carry(self, key_expr: str) -> bool:
        """Whether a subscription on key_expr can receive a message this bus decides."""
        b = self._prefix
        kinds = [b + "robot/*/pose", b + "robot/*/cmd"] + ([b + "leader/ref", b + "cell/*/*/*"] if self.me >= 0 else [])
        return any(intersects(key_expr, k) for k in kinds)

    def _link(self, cls: int, sender: int, receiver: int):
        link = self._links.get((cls, sender, receiver))
        if link is None:
            link = self._links[(cls, sender, receiver)] = self.table.link(cls, sender, receiver)
        return link

    def decide(self, key: str, payload: bytes) -> int:
        """This message's fate: -1 lost, 0 delivered now, d > 0 late by d control periods (counted)."""
        c = self.classify(key)
        if c is None:
            return 0
        cls, sender, receiver = c
        try:
            msg = protocol.decode(payload, _KIND[cls], sender if cls == fg.CLS_STATE else None)
        except ProtocolError:
            return 0  # the receiver refuses it and counts it
        k, t = msg.seq, msg.t
        with self._lock:
            link = self._link(cls, sender, receiver)
            if _chain_steps(link, k) > MAX_CHAIN_STEPS:
                self.undecided += 1
                if self.undecided == 1:
                    log.warning("fault bus: %s with seq %d is too far from the link's last (the burst chain would take "
                                "more than %d steps): passed through undecided", key, k, MAX_CHAIN_STEPS)
                return 0
            lost, late = link.decide(k, t)
            if lost:
                self.dropped[cls] += 1
                if t > self.lost_t[cls]:
                    self.lost_t[cls] = t
                return -1
            if late > 0:
                self.delayed[cls] += 1
            return late

    def hold_s(self, late: int) -> float:
        """Wall seconds a message late by `late` control periods is held."""
        return late * self.dt / max(1e-9, float(self._speed()))

    def counters(self) -> dict:
        """{"dropped": {class: n}, "delayed": {class: n}} so far."""
        with self._lock:
            return {"dropped": dict(zip(CLASS_NAMES, self.dropped)), "delayed": dict(zip(CLASS_NAMES, self.delayed))}

    # ------------------------------------------------------------------ receiving

    def subscribe(self, key_expr: str, fn) -> Closable:
        if not self._may_carry(key_expr):
            return self.inner.subscribe(key_expr, fn)
        sub = _Held(self, guarded(fn, self.errors, "a subscriber"))
        sub.handle = self.inner.subscribe(key_expr, lambda key, payload: sub.take(key, payload, None, False))
        return sub

    def subscribe_raw(self, key_expr: str, fn) -> Closable:
        if not self._may_carry(key_expr):
            return self.inner.subscribe_raw(key_expr, fn)
        sub = _Held(self, guarded(fn, self.errors, "a subscriber"))
        sub.handle = self.inner.subscribe_raw(key_expr, lambda key, payload, att: sub.take(key, payload, att, True))
        return sub

    def inbox(self, key_expr: str, depth: int = 64):
        box = self.inner.inbox(key_expr, depth)
        if not self._may_carry(key_expr):
            return box
        return FaultInbox(self, box)

    def pump(self) -> int:
        """Deliver every held callback message now due (the timer thread does this by itself); returns
        how many actions ran. Inboxes release theirs in drain() and wait()."""
        return self._timer.run_due()

    def _at(self, due: float, action: Callable[[], None]) -> None:
        if not self._detached:
            self._timer.at(due, action)

    def detach(self) -> None:
        """Stop the timer (nothing held is delivered any more); the wrapped bus stays open."""
        self._detached = True
        self._timer.close()

    # ------------------------------------------------------------------ everything else: the wrapped bus

    def put(self, key: str, payload: bytes, reliable: bool = False, loopback: bool = True,
            attachment: bytes | None = None) -> None:
        self.inner.put(key, payload, reliable=reliable, loopback=loopback, attachment=attachment)

    def wanted(self, key: str) -> bool:
        return self.inner.wanted(key)

    def hint(self, key: str) -> None:
        self.inner.hint(key)

    def token(self, key: str) -> Closable:
        return self.inner.token(key)

    def watch_alive(self, key_expr: str, fn) -> Closable:
        return self.inner.watch_alive(key_expr, fn)

    def alive_now(self, key_expr: str, timeout_s: float = 1.0) -> list[str]:
        return self.inner.alive_now(key_expr, timeout_s)

    def serve(self, key_expr: str, fn) -> Closable:
        return self.inner.serve(key_expr, fn)

    def query(self, key_expr: str, timeout_s: float = 2.0):
        return self.inner.query(key_expr, timeout_s)

    def close(self) -> None:
        self.detach()
        self.inner.close()


def _chain_steps(link, k: int) -> int:
    """The burst-chain steps link.decide(k, ...) would take (0 without burst rules)."""
    most = 0
    for row, _key, p, burst, *_ in link.drops:
        if burst > 1.0 and 0.0 < p < 1.0:
            ck = int(link.chains[row, fg.C_K])
            most = max(most, k if ck < 0 or ck > k else k - ck)
    return most


class _Held:
    """A subscription through the fault bus: its messages delivered now, held for later, or lost."""

    def __init__(self, bus: FaultBus, fn) -> None:
        self.bus, self.fn = bus, fn
        self.handle: Closable | None = None
        self.held = 0
        self.closed = False

    def take(self, key: str, payload: bytes, att: bytes | None, raw: bool) -> None:
        fate = self.bus.decide(key, payload)
        if fate < 0:
            return
        if fate == 0:
            self._deliver(key, payload, att, raw)
            return
        due = self.bus.clock.monotonic() + self.bus.hold_s(fate)
        with self.bus._lock:
            if self.held >= HELD_MAX:
                self.bus.overflow += 1
                late = None
            else:
                self.held += 1
                late = True
        if late is None:
            self._deliver(key, payload, att, raw)
            return

        def later() -> None:
            with self.bus._lock:
                self.held -= 1
            if not self.closed:
                self._deliver(key, payload, att, raw)

        self.bus._at(due, later)

    def _deliver(self, key: str, payload: bytes, att: bytes | None, raw: bool) -> None:
        if raw:
            self.fn(key, payload, att)
        else:
            self.fn(key, payload)

    def close(self) -> None:
        self.closed = True
        if self.handle is not None:
            self.handle.close()


class FaultInbox:
    """An inbox through the fault bus (the Inbox interface of swarm.net.bus). Not thread-safe beyond
    what an inbox is: one thread drains and waits, any thread may wake()."""

    def __init__(self, bus: FaultBus, inner) -> None:
        self.bus, self.inner = bus, inner
        self.held: list[tuple[float, int, str, bytes]] = []  # (due, order, key, payload): a heap
        self._order = itertools.count()
        self._wake_at = float("inf")  # the earliest due time a timer wake-up is set for

    def _take(self, items: list[tuple[str, bytes]]) -> list[tuple[str, bytes]]:
        out = []
        now = None
        for key, payload in items:
            fate = self.bus.decide(key, payload)
            if fate == 0:
                out.append((key, payload))
            elif fate > 0:
                now = self.bus.clock.monotonic() if now is None else now
                heapq.heappush(self.held, (now + self.bus.hold_s(fate), next(self._order), key, payload))
        early = []
        while len(self.held) > HELD_MAX:  # the earliest due goes now rather than be held beyond the bound
            _, _, key, payload = heapq.heappop(self.held)
            early.append((key, payload))
        if early:
            with self.bus._lock:
                self.bus.overflow += len(early)
        return early + out

    def _release(self) -> list[tuple[str, bytes]]:
        """The held messages due now, by due time."""
        out = []
        if self.held:
            now = self.bus.clock.monotonic()
            while self.held and self.held[0][0] <= now:
                _, _, key, payload = heapq.heappop(self.held)
                out.append((key, payload))
        return out

    def _arm(self) -> None:
        """Have the timer wake a blocked wait() when the next held message falls due."""
        if self.held and self.held[0][0] < self._wake_at:
            due = self._wake_at = self.held[0][0]

            def ring() -> None:
                if self._wake_at == due:
                    self._wake_at = float("inf")
                try:
                    self.inner.wake()
                except Exception as e:  # the inbox is closing, or cannot be woken (a wildcard zenoh inbox)
                    log.debug("fault bus: no wake-up for a held message: %s", e)

            self.bus._at(due, ring)

    def drain(self) -> list[tuple[str, bytes]]:
        fresh = self._take(self.inner.drain())
        out = self._release() + fresh
        self._arm()
        return out

    def wait(self) -> list[tuple[str, bytes]]:
        ready = self._release()
        if ready:
            self._arm()
            return ready
        self._arm()
        got = self._take(self.inner.wait())
        out = self._release() + got
        self._arm()
        return out

    def wake(self) -> None:
        self.inner.wake()

    def close(self) -> None:
        self.held.clear()
        self.inner.close()


class _Timer:
    """Actions at monotonic times (the clock's), in order of due time: on a daemon thread of its own
    (threaded), or when run_due() is called."""

    def __init__(self, clock, threaded: bool) -> None:
        self.clock, self.threaded = clock, threaded
        self.heap: list[tuple[float, int, Callable[[], None]]] = []
        self.order = itertools.count()
        self.cond = threading.Condition(threading.Lock())
        self.thread: threading.Thread | None = None
        self.closed = False

    def at(self, due: float, action: Callable[[], None]) -> None:
        with self.cond:
            if self.closed:
                return
            heapq.heappush(self.heap, (due, next(self.order), action))
            if self.thread is None and self.threaded:
                self.thread = threading.Thread(target=self._run, name="faultbus-timer", daemon=True)
                self.thread.start()
            self.cond.notify()

    def run_due(self) -> int:
        ran = 0
        while True:
            with self.cond:
                if not self.heap or self.heap[0][0] > self.clock.monotonic() or self.closed:
                    return ran
                _, _, action = heapq.heappop(self.heap)
            try:
                action()
            except Exception as e:  # an action never takes the timer down (handlers are guarded already)
                log.warning("fault bus: a held message's delivery raised %s: %s", type(e).__name__, e)
            ran += 1

    def _run(self) -> None:
        while True:
            with self.cond:
                if self.closed:
                    return
                left = self.heap[0][0] - self.clock.monotonic() if self.heap else None
                if left is None or left > 0:
                    self.cond.wait(None if left is None else left)
                    continue
            self.run_due()

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.heap.clear()
            self.cond.notify()
        t = self.thread
        if t is not None and t is not threading.current_thread():
            t.join(1.0)

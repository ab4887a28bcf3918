"""The small bus every process talks through: the one place that touches zenoh.

    bus.put(key, payload, reliable=False)      # reliable: congestion control BLOCK
    bus.put(key, payload, loopback=False)      # not to this bus's own subscribers (zenoh: remote only)
    bus.put(key, payload, attachment=b"...")   # with a zenoh attachment (bytes beside the payload)
    bus.wanted(key)                             # would anyone receive a put on key? (skip costly work if not)
    sub = bus.subscribe(key_expr, fn)           # fn(key: str, payload: bytes), on a bus thread
    sub = bus.subscribe_raw(key_expr, fn)       # fn(key, payload, attachment: bytes | None), same thread
    sub = bus.subscribe_sink(key_expr, sink)    # a compiled sink (swarm.proto._wire.StateSink), same thread
    box = bus.inbox(key_expr, depth=64)         # kept until box.drain() -> [(key, payload), ...] (newest depth)
    box.wait()                                  # block until something came (or box.wake()): what is here then
    tok = bus.token(key)                        # a liveliness token; tok.close() withdraws it
    sub = bus.watch_alive(key_expr, fn)         # fn(key: str, alive: bool); current tokens first
    sub = bus.serve(key_expr, fn)               # a queryable: fn(key: str) -> bytes, or None: no reply
    replies = bus.query(key_expr, timeout_s)    # [(key, payload), ...]
    bus.close()

Two implementations behind the same narrow interface: ZenohBus (a zenoh session: client of a
router, or the router itself) and MemoryBus (a process-local network for unit tests:
several MemoryBus objects on one MemoryNet behave like processes on one router). The
interface is narrow on purpose so that a fault-injecting wrapper can stand around it.
Key expressions follow zenoh: `*` is one chunk, `**` any number of chunks. Attachments exist for
peers that need them (a ROS 2 node under rmw_zenoh drops a sample without one: docs/ros2.md);
swarm's own messages carry none.
"""

from __future__ import annotations

import secrets
import threading
from collections import OrderedDict, deque
from typing import TYPE_CHECKING, Any, Callable, Protocol, final

from swarm.proto import protocol as _protocol

if TYPE_CHECKING:
    import zenoh

Handler = Callable[[str, bytes], None]
AliveHandler = Callable[[str, bool], None]
RawHandler = Callable[[str, bytes, bytes | None], None]  # key, payload, attachment (None: the sample had none)


class Closable(Protocol):
    def close(self) -> None: ...


class Inbox(Protocol):
    def drain(self) -> list[tuple[str, bytes]]: ...
    def wait(self) -> list[tuple[str, bytes]]: ...  # blocks until a message or wake(): what is here then ([] if woken)
    def wake(self) -> None: ...  # from another thread: a blocked wait() returns
    def close(self) -> None: ...


class Bus(Protocol):
    def put(self, key: str, payload: bytes, reliable: bool = False, loopback: bool = True,
            attachment: bytes | None = None) -> None: ...
    def wanted(self, key: str) -> bool: ...
    def hint(self, key: str) -> None: ...  # a concrete key this process will receive often (ZenohBus.hint)
    def subscribe(self, key_expr: str, fn: Handler) -> Closable: ...
    def subscribe_raw(self, key_expr: str, fn: RawHandler) -> Closable: ...
    def subscribe_sink(self, key_expr: str, sink) -> Closable: ...  # optional: a bus without it gets fn callbacks
    def inbox(self, key_expr: str, depth: int = 64) -> Inbox: ...
    def token(self, key: str) -> Closable: ...
    def watch_alive(self, key_expr: str, fn: AliveHandler) -> Closable: ...
    def alive_now(self, key_expr: str, timeout_s: float = 1.0) -> list[str]: ...  # the tokens there now, sorted
    def serve(self, key_expr: str, fn: Callable[[str], bytes | None]) -> Closable: ...
    def query(self, key_expr: str, timeout_s: float = 2.0) -> list[tuple[str, bytes]]: ...
    def close(self) -> None: ...


def matches(expr: str, key: str) -> bool:
    """Does zenoh key expression `expr` (with * and **) match the concrete `key`?"""
    e, k = expr.split("/"), key.split("/")

    def go(i: int, j: int) -> bool:
        if i == len(e):
            return j == len(k)
        if e[i] == "**":
            return any(go(i + 1, jj) for jj in range(j, len(k) + 1))
        if j == len(k):
            return False
        return (e[i] == "*" or e[i] == k[j]) and go(i + 1, j + 1)

    return go(0, 0)


def guarded(fn, errors, what: str, default=None):
    """fn wrapped so that no exception escapes into the bus's thread: it is counted in `errors` (a
    swarm.proto.protocol.BadMessages), logged (rate-limited) with the key, and the callback returns
    `default`. Every callback a bus runs goes through this: a message that trips a bug in a handler
    costs that message, never the process or zenoh's thread."""

    def call(key, *args):
        try:
            return fn(key, *args)
        except Exception as e:
            errors.reject(key, RuntimeError(f"{what} raised {type(e).__name__}: {e}"))
            return default

    return call


def _errors():
    import logging

    return _protocol.BadMessages(logging.getLogger("swarm.bus"))


# --------------------------------------------------------------------------- in memory


class _Handle:
    def __init__(self, on_close: Callable[[], None]):
        self._on_close = on_close
        self._closed = False

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._on_close()


class _MemoryInbox:
    def __init__(self, depth: int) -> None:
        self.items: deque[tuple[str, bytes]] = deque(maxlen=depth)
        self.cond = threading.Condition()
        self.woken = False
        self.handle: Closable | None = None

    def push(self, key: str, payload: bytes) -> None:
        with self.cond:
            self.items.append((key, payload))
            self.cond.notify_all()

    def drain(self) -> list[tuple[str, bytes]]:
        with self.cond:
            out = list(self.items)
            self.items.clear()
        return out

    def wait(self) -> list[tuple[str, bytes]]:
        with self.cond:
            self.cond.wait_for(lambda: self.items or self.woken)
            self.woken = False
        return self.drain()

    def wake(self) -> None:
        with self.cond:
            self.woken = True
            self.cond.notify_all()

    def close(self) -> None:
        if self.handle is not None:
            self.handle.close()


@final
class _Raw:
    """A subscribe_raw() handler on a MemoryNet: put() hands it the attachment too."""

    __slots__ = ("fn",)

    def __init__(self, fn: RawHandler) -> None:
        self.fn = fn


class MemoryNet:
    """A process-local 'router': delivers synchronously, in order, to every matching subscriber."""

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.subs: list[tuple[str, Handler | _Raw, MemoryBus]] = []  # (key expression, handler, the bus it is on)
        self.tokens: dict[str, int] = {}
        self.watchers: list[tuple[str, AliveHandler]] = []
        self.queryables: list[tuple[str, Callable[[str], bytes | None]]] = []
        self.delivered = 0  # messages handed to subscribers (for traffic assertions)


class MemoryBus:
    """One 'process' on a MemoryNet."""

    def __init__(self, net: MemoryNet):
        self.net = net
        self._handles: list[_Handle] = []
        self.errors = _errors()  # exceptions of this bus's callbacks, counted (see guarded)

    def put(self, key: str, payload: bytes, reliable: bool = False, loopback: bool = True,
            attachment: bytes | None = None) -> None:
        with self.net.lock:
            targets = [fn for expr, fn, owner in self.net.subs if matches(expr, key) and (loopback or owner is not self)]
            self.net.delivered += len(targets)
        att = None if attachment is None else bytes(attachment)
        for fn in targets:
            if type(fn) is _Raw:
                fn.fn(key, bytes(payload), att)
            else:
                fn(key, bytes(payload))

    def wanted(self, key: str) -> bool:
        """Whether some subscriber would receive a put on `key` (a publisher may skip costly work if not)."""
        with self.net.lock:
            return any(matches(expr, key) for expr, _fn, _owner in self.net.subs)

    def hint(self, key: str) -> None:
        """Nothing to resolve in memory (ZenohBus.hint)."""

    def _keep(self, lst: list, item) -> _Handle:
        with self.net.lock:
            lst.append(item)

        def remove() -> None:
            with self.net.lock:
                if item in lst:
                    lst.remove(item)

        h = _Handle(remove)
        self._handles.append(h)
        return h

    def subscribe(self, key_expr: str, fn: Handler) -> Closable:
        return self._keep(self.net.subs, (key_expr, guarded(fn, self.errors, "a subscriber"), self))

    def subscribe_raw(self, key_expr: str, fn: RawHandler) -> Closable:
        """subscribe(), and fn also gets the sample's attachment (None if it had none)."""
        return self._keep(self.net.subs, (key_expr, _Raw(guarded(fn, self.errors, "a subscriber")), self))

    def subscribe_sink(self, key_expr: str, sink) -> Closable:
        """subscribe() for a compiled sink (swarm.proto._wire.StateSink): it takes (key, payload) here."""
        return self.subscribe(key_expr, sink.take)

    def inbox(self, key_expr: str, depth: int = 64) -> Inbox:
        box = _MemoryInbox(depth)
        box.handle = self.subscribe(key_expr, box.push)
        return box

    def token(self, key: str) -> Closable:
        with self.net.lock:
            self.net.tokens[key] = self.net.tokens.get(key, 0) + 1
            first = self.net.tokens[key] == 1
            watchers = [fn for expr, fn in self.net.watchers if matches(expr, key)]
        if first:
            for fn in watchers:
                fn(key, True)

        def withdraw() -> None:
            with self.net.lock:
                self.net.tokens[key] -= 1
                gone = self.net.tokens[key] == 0
                if gone:
                    del self.net.tokens[key]
                ws = [fn for expr, fn in self.net.watchers if matches(expr, key)]
            if gone:
                for fn in ws:
                    fn(key, False)

        h = _Handle(withdraw)
        self._handles.append(h)
        return h

    def watch_alive(self, key_expr: str, fn: AliveHandler) -> Closable:
        fn = guarded(fn, self.errors, "a liveliness watcher")
        with self.net.lock:
            current = [k for k in self.net.tokens if matches(key_expr, k)]
        for k in sorted(current):
            fn(k, True)
        return self._keep(self.net.watchers, (key_expr, fn))

    def alive_now(self, key_expr: str, timeout_s: float = 1.0) -> list[str]:
        with self.net.lock:
            return sorted(k for k in self.net.tokens if matches(key_expr, k))

    def serve(self, key_expr: str, fn: Callable[[str], bytes | None]) -> Closable:
        return self._keep(self.net.queryables, (key_expr, guarded(fn, self.errors, "a queryable")))

    def query(self, key_expr: str, timeout_s: float = 2.0) -> list[tuple[str, bytes]]:
        with self.net.lock:
            qs = [(expr, fn) for expr, fn in self.net.queryables if matches(key_expr, expr) or matches(expr, key_expr)]
        out = []
        for expr, fn in qs:
            reply = fn(key_expr)
            if reply is not None:
                out.append((key_expr if "*" not in key_expr else expr, reply))
        return out

    def close(self) -> None:
        for h in reversed(self._handles):
            h.close()
        self._handles.clear()


# --------------------------------------------------------------------------- zenoh


def zenoh_config(mode: str = "client", connect: list[str] | None = None, listen: list[str] | None = None,
                 config_file: str | None = None, lease_ms: int = 1000, multicast: bool = False, base=None,
                 ingress_checks: bool = True, zid: str | None = None):
    """A zenoh.Config for our topology (docs/runtime.md): explicit endpoints, multicast scouting off
    unless asked, a short lease so a hung process is noticed in about 1 s, zenoh's own size limits and
    wildcard guard on the way in (ingress_checks=False leaves both out: a client whose router checks them,
    --router-checks). zid: the session's zenoh id (hex), else zenoh's random one.
    Our settings go on top of `base` (an identity's config from swarm.net.secure) or of config_file
    (--zenoh-config), or of zenoh's defaults."""
    import json

    import zenoh

    if base is not None:
        conf = base
    else:
        conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    if zid is not None:
        conf.insert_json5("id", json.dumps(zid))
    conf.insert_json5("scouting/multicast/enabled", "true" if multicast else "false")
    conf.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
    # a reliable put to a peer that takes nothing (behind a silent network cut) blocks the sender, the
    # router included, until the link is closed: zenoh's default is 5 s, for each such peer in turn, and the
    # whole swarm stalls meanwhile; a peer that cannot take data for a lease is gone anyway (docs/runtime.md)
    conf.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close", str(int(lease_ms) * 1000))
    # a session that dropped (its lease missed on a lossy link, a cut that ended) comes back in about a second, not
    # in zenoh's 10 s handshake timeout and 1-4 s retry period (docs/faults.md, Cutting a network)
    conf.insert_json5("transport/unicast/open_timeout", "2000")
    conf.insert_json5("connect/retry", json.dumps({"period_init_ms": 250, "period_max_ms": 1000,
                                                   "period_increase_factor": 2}))
    # no shared memory: zenoh would carry a payload beyond 3 kB between two processes of one machine in it (a
    # world's config replies), and from then on each process that took one runs a watchdog thread, 41 of them in
    # a 37-robot swarm for 1.4 % of the machine; swarm's messages are small, and most cross machines
    conf.insert_json5("transport/shared_memory/enabled", "false")
    # small batches: lock-step traffic is many ~100-byte messages
    conf.insert_json5("transport/link/tx/batch_size", "4096")
    conf.insert_json5("transport/link/rx/buffer_size", "4096")
    # payloads beyond the codec's limits are dropped by zenoh itself on the way in, so an
    # oversized payload never reaches a subscriber (the codec would refuse it, but only after it came)
    if ingress_checks:
        conf.insert_json5("low_pass_filter", json.dumps(size_limits()))
    # ... but zenoh applies that filter to a whole message, once it has put the message's fragments back
    # together, up to 1 GiB by default: 12 puts of 64 MiB from a client left the router 84-160 MiB larger
    # (bench/router_memory.py). Each link's defragmentation stops at the largest message the swarm sends:
    # a large kind at the codec's limit (a snapshot is ~83 N bytes for N robots: 164 kB at 2000, 8.3 MB at
    # MAX_ROBOTS) and zenoh's header (key, timestamp, encoding: bytes; MAX_PAYLOAD is ample). zenoh drops
    # a message beyond it as its fragments come and keeps the link open (docs/security.md).
    from swarm.proto.protocol import MAX_LARGE_PAYLOAD, MAX_PAYLOAD

    conf.insert_json5("transport/link/rx/max_message_size", str(MAX_LARGE_PAYLOAD + MAX_PAYLOAD))
    # a put on a key expression with wildcards (cell/*/*/5) reaches every subscription it intersects: dropped
    # on the way in, before routing or any callback (wildcard_guard), after any downsampling of the user's
    if ingress_checks:
        try:
            theirs = json.loads(conf.get_json("downsampling") or "null") or []
        except Exception:  # not set
            theirs = []
        conf.insert_json5("downsampling", json.dumps(list(theirs) + [wildcard_guard()]))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    if listen is not None:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    return conf


def plain_config(mode: str, connect: list[str] | None = None, listen: list[str] | None = None):
    """zenoh's own defaults with explicit endpoints and multicast scouting off: what another zenoh program
    (somebody else's router, an attacker's client) runs, without any of zenoh_config's settings."""
    import json

    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    return conf


WILDCARD_CHUNK = "$*~$*"  # a chunk with a "~": no key the swarm puts has one (ids, cells and kinds are [A-Za-z0-9_-])


def wildcard_guard() -> dict:
    """A zenoh downsampling item that drops, on the way in (ingress), every put or delete whose key
    expression has a wildcard in any chunk: a rate of 0 (zenoh then lets none through) on key expressions
    with a "~" in a chunk. No concrete key of the swarm has one, so no concrete key intersects them, while
    every key expression with a wildcard chunk (*, **, $*) after the first does (cell/*/*/5 meets
    cell/~/x/5). zenoh matches a downsampling rule by intersection, not inclusion; its access control
    (--secure) matches by inclusion and cannot tell a wildcard put from a concrete one: a robot allowed
    cell/*/*/5 may put on that expression itself. A concrete key (even under a wildcard fleet,
    swarm/*/cell/1/2/5, which meets each subscription at most once) goes through, and the receiver refuses it
    (keys.cell_robot, keys.parse). docs/security.md."""
    w = WILDCARD_CHUNK
    return {"id": "swarm-wildcards", "flows": ["ingress"], "messages": ["put", "delete"],
            "rules": [{"key_expr": f"{w}/**", "freq": 0.0}, {"key_expr": f"*/{w}/**", "freq": 0.0},
                      {"key_expr": f"*/*/**/{w}/**", "freq": 0.0}]}


def size_limits() -> list[dict]:
    """zenoh low_pass_filter rules: the large kinds (snapshot, obstacles, run, bodies) up to the
    codec's large limit, every other swarm key and the ROS 2 topics a drive uses up to the small one.
    On ingress only: every router and every process checks what comes in, so a payload is checked where
    it enters our router and again where it enters a process (behind a router that is not ours), but in
    the processes swarm up starts on its own router (--router-checks); egress rules checked the same
    payloads twice more (docs/protocol.md)."""
    from swarm.proto.protocol import MAX_LARGE_PAYLOAD, MAX_PAYLOAD

    large = [f"swarm/*/world/{k}" for k in ("snapshot", "obstacles", "run", "bodies")]
    small = ["swarm/*/robot/**", "swarm/*/cell/**", "swarm/*/leader/**", "swarm/*/alive/**", "swarm/*/estop",
             "swarm/*/world/clock", "swarm/*/world/progress", "swarm/*/world/config/*", "swarm/*/world/events",
             "swarm/*/world/claim/*", "**/cmd_vel/**", "**/cmd_vel", "**/odom/**", "**/odom"]
    everything = ["put", "delete", "query", "reply"]
    return [{"id": "swarm-small", "flows": ["ingress"], "messages": everything, "key_exprs": small,
             "size_limit": MAX_PAYLOAD},
            {"id": "swarm-large", "flows": ["ingress"], "messages": everything, "key_exprs": large,
             "size_limit": MAX_LARGE_PAYLOAD}]


# zenoh's runtime settings (the ZENOH_RUNTIME environment variable; docs/runtime.md, and docs/faults.md,
# Cutting a network). They must be in the environment before zenoh starts its runtime: open_bus sets them.
#
# zenoh closes a TCP link with SO_LINGER 10 s (compiled in), so closing a link that still holds unsent
# data (its peer is behind a network cut) blocks the worker thread that closes it for up to 10 s
# (eclipse-zenoh/zenoh#1101). Hence at least one worker more than such a close can take:
#
# - many small processes (robots, the leader): every pool handed over to the application pool (half the
#   threads and much less CPU of 40 processes on 2 cores than zenoh's defaults), with 2 workers: with one,
#   a robot cut off from its router froze its whole session for 10 s on the close and came back 10-20 s
#   after the cut ended (tests/integration/test_netns.py); 2 cost no measurable lock-step speed;
ZENOH_RUNTIME = "(app:(worker_threads:2),rx:(handover:app),tx:(handover:app),acc:(handover:app),net:(handover:app))"
# - the router: every link it loses to a cut closes on a receiving worker; with zenoh's 2, a cut of 4 robots
#   blocked both for 10 s and the router received nothing meanwhile, so the robots outside the cut lost it
#   too. 16 receiving workers: a cut of up to 15 links at once leaves the router receiving.
ROUTER_RUNTIME = "(rx:(worker_threads:16))"


PUBLISHERS = 64  # declared publishers a ZenohBus keeps (a robot uses 3 or 4: cmd, status, its cell)
WANTED = 256  # keys whose matching status wanted() keeps by a listener (a world: 1; preflight: 2 a robot)
KEY_HINTS = 1024  # keys a ZenohBus keeps declared for hint() (a robot of a 37-robot run uses a few hundred)


class ZenohBus:
    """A Bus over one zenoh session. Close it (or use `with`): an open session with callback
    subscribers hangs the interpreter at exit. Never fork after creating one."""

    # another session's messages come to callbacks on zenoh's threads (a put's own subscribers in this
    # session are called inside the put: a robot hears nothing it sends, its states go out remote-only), so
    # a lock-step robot may run its tick in one (agents.robot.Agent, inline)
    threaded_callbacks = True

    def __init__(self, conf, direct: bool = True) -> None:
        import zenoh

        self._z = zenoh
        self.direct = direct
        _init_zenoh_log(zenoh)
        self.session = zenoh.open(conf)
        self._handles: list[Closable] = []
        self._closed = False
        self._pubs: OrderedDict[tuple[str, bool, bool], zenoh.Publisher] = OrderedDict()
        self._wanted: dict[str, _Matching] = {}  # key -> its matching status, as wanted() keeps it
        self._pub_lock = threading.Lock()
        self._hints: dict[str, zenoh.KeyExpr] = {}
        self.errors = _errors()  # exceptions of this bus's callbacks, counted (see guarded)

    def __enter__(self) -> "ZenohBus":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def put(self, key: str, payload: bytes, reliable: bool = False, loopback: bool = True,
            attachment: bytes | None = None) -> None:
        if attachment is None:
            try:  # the common case, declared: no lock (OrderedDict's methods are atomic under the GIL)
                self._pubs.move_to_end((key, reliable, loopback))
                pub = self._pubs[(key, reliable, loopback)]
            except KeyError:  # not declared (or just evicted by another thread)
                pub = self._publisher(key, reliable, loopback)
            pub.put(payload)
        else:
            self._publisher(key, reliable, loopback).put(payload, attachment=attachment)

    def wanted(self, key: str) -> bool:
        """Whether some subscriber would receive a put on `key`: zenoh's matching status, kept up to date by a
        matching listener from the first call, for up to WANTED keys (asked each time, the status waited on the
        session's routing, and a world asks before every tick's snapshot: docs/performance.md, "The world's part
        of a lock-step tick"). False once the bus is closed."""
        m = self._wanted.get(key)
        if m is not None:
            return m.now
        with self._pub_lock:
            m = self._wanted.get(key)
            if m is not None:
                return m.now
            if self._closed:
                return False
            if len(self._wanted) >= WANTED:  # keys past the cap are asked each time
                return bool(self._publisher_locked(key, False, True).matching_status.matching)
            m = _Matching()
            # its own publisher: the LRU of _publisher may let one go (Any: zenoh's stub calls its matching_status a
            # bool; it is a MatchingStatus, as the listener's argument is). The listener runs on zenoh's thread
            # (indirect=False: no thread of its own), and tells the status at once if a subscriber matches already
            pub: Any = self.session.declare_publisher(key)
            try:
                listener = pub.declare_matching_listener(self._z.handlers.Callback(m.changed, indirect=False))
            except BaseException:
                pub.undeclare()
                raise
            self._handles += [_Undeclare(pub), _Undeclare(listener)]
            m.first(bool(pub.matching_status.matching))
            self._wanted[key] = m  # only now: a reader without the lock sees a status, never a half-made entry
            return m.now

    def _publisher(self, key: str, reliable: bool, loopback: bool = True):
        """A declared publisher per key, kept for the next put (LRU, at most PUBLISHERS): a declared
        key is resolved once, and a put on it costs about a third of a session.put on a string."""
        with self._pub_lock:
            return self._publisher_locked(key, reliable, loopback)

    def _publisher_locked(self, key: str, reliable: bool, loopback: bool):
        """_publisher, under _pub_lock."""
        pub = self._pubs.get((key, reliable, loopback))
        if pub is not None:
            self._pubs.move_to_end((key, reliable, loopback))
            return pub
        cc = self._z.CongestionControl.BLOCK if reliable else self._z.CongestionControl.DROP
        where = self._z.Locality.ANY if loopback else self._z.Locality.REMOTE
        pub = self._pubs[(key, reliable, loopback)] = self.session.declare_publisher(
            key, congestion_control=cc, allowed_destination=where)
        if len(self._pubs) > PUBLISHERS:
            self._pubs.popitem(last=False)[1].undeclare()
        return pub

    def hint(self, key: str) -> None:
        """A concrete key this process will receive on many times, through a wildcard subscription (a
        neighbour's cell key, a robot's command key): declared to zenoh (declare_keyexpr), so that its
        session resolves the key's route once and keeps it. Without it, zenoh matches every sample on a key
        it does not know against all of its subscriptions again (Resource::get_matches): about 4 % of the
        whole machine's CPU in a 37-robot real-time run (docs/performance.md, "Key hints"). At most KEY_HINTS are kept: past
        that they are all undeclared and it starts over (keys of robots long gone, or a stranger's)."""
        with self._pub_lock:
            if key in self._hints or self._closed:
                return
            if len(self._hints) >= KEY_HINTS:
                for ke in self._hints.values():
                    self.session.undeclare(ke)
                self._hints.clear()
            self._hints[key] = self.session.declare_keyexpr(key)

    def _keep(self, h):
        self._handles.append(h)
        return h

    def subscribe(self, key_expr: str, fn: Handler) -> Closable:
        errors = self.errors

        def cb(sample) -> None:  # guarded(), inlined: one Python frame less per message on zenoh's thread
            pin_thread()
            key = str(sample.key_expr)
            try:
                fn(key, sample.payload.to_bytes())
            except Exception as e:
                errors.reject(key, RuntimeError(f"a subscriber raised {type(e).__name__}: {e}"))

        return self._keep(_Undeclare(self.session.declare_subscriber(key_expr, self._handler(cb))))

    def subscribe_raw(self, key_expr: str, fn: RawHandler) -> Closable:
        """subscribe(), and fn also gets the sample's attachment (None if it had none)."""
        fn = guarded(fn, self.errors, "a subscriber")

        def cb(sample) -> None:
            pin_thread()
            a = sample.attachment
            fn(str(sample.key_expr), sample.payload.to_bytes(), None if a is None else a.to_bytes())

        return self._keep(_Undeclare(self.session.declare_subscriber(key_expr, self._handler(cb))))

    def subscribe_sink(self, key_expr: str, sink) -> Closable:
        """subscribe() for a compiled sink (swarm.proto._wire.StateSink): zenoh hands it each sample on its
        receiving thread, and it reads the key and payload itself (no Python frame per message; it never
        raises: it counts its own errors)."""
        return self._keep(_Undeclare(self.session.declare_subscriber(key_expr, self._handler(sink))))

    def inbox(self, key_expr: str, depth: int = 64) -> Inbox:
        """Samples wait in a zenoh ring channel (the newest `depth`) until drain(): zenoh's thread
        never runs Python for them (no GIL, no callback), and the owner decodes them in one batch.
        A robot's neighbour states take this path in real time: its receiving thread never waits for the GIL
        (docs/performance.md, "Tried and dropped")."""
        sub = self.session.declare_subscriber(key_expr, self._z.handlers.RingChannel(depth))
        return self._keep(_ZenohInbox(sub, self.session, key_expr, self._z))

    def _handler(self, cb):
        # direct: on zenoh's receiving thread, in arrival order (the lock-step protocol relies on
        # the order of one link); such a callback must only enqueue. Otherwise a Python thread.
        return self._z.handlers.Callback(cb, indirect=False) if self.direct else cb

    def token(self, key: str) -> Closable:
        return self._keep(_Undeclare(self.session.liveliness().declare_token(key)))

    def watch_alive(self, key_expr: str, fn: AliveHandler) -> Closable:
        put_kind = self._z.SampleKind.PUT
        fn = guarded(fn, self.errors, "a liveliness watcher")

        def cb(sample) -> None:
            pin_thread()
            fn(str(sample.key_expr), sample.kind == put_kind)

        return self._keep(_Undeclare(self.session.liveliness().declare_subscriber(key_expr, self._handler(cb),
                                                                                  history=True)))

    def alive_now(self, key_expr: str, timeout_s: float = 1.0) -> list[str]:
        """The liveliness tokens on key_expr now (a liveliness query: the router answers for the tokens it holds)."""
        out = set()
        for reply in self.session.liveliness().get(key_expr, timeout=timeout_s):
            if reply.ok is not None:
                out.add(str(reply.ok.key_expr))
        return sorted(out)

    def serve(self, key_expr: str, fn: Callable[[str], bytes | None]) -> Closable:
        fn = guarded(fn, self.errors, "a queryable")

        def answer(asked: str, query) -> None:
            reply = fn(asked)
            if reply is not None:
                query.reply(asked if "*" not in asked else key_expr, reply)

        answer = guarded(answer, self.errors, "a queryable's reply")

        def cb(query) -> None:
            pin_thread()
            answer(str(query.key_expr), query)

        return self._keep(_Undeclare(self.session.declare_queryable(key_expr, cb)))

    def query(self, key_expr: str, timeout_s: float = 2.0) -> list[tuple[str, bytes]]:
        out = []
        for reply in self.session.get(key_expr, timeout=timeout_s):
            if reply.ok is not None:
                out.append((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))
        return out

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        with self._pub_lock:
            pubs, self._pubs = list(self._pubs.values()), OrderedDict()
            self._hints = {}  # the session's close lets its declared keys go
        for h in [_Undeclare(p) for p in pubs] + self._handles[::-1]:
            try:
                h.close()
            except Exception:  # already gone with the session: nothing left to release
                pass
        self.session.close()


_LOG_READY = False
_PINNED = threading.local()


def _pin_thread_ctypes() -> None:
    if not getattr(_PINNED, "done", False):
        import ctypes

        _PINNED.done = True
        ctypes.pythonapi.PyGILState_Ensure()


# Every callback zenoh runs calls this first, on zenoh's thread with the GIL held: it keeps that thread's
# Python thread state for the life of the process. Without it CPython makes and deletes a thread state for
# each callback (pyo3 takes the GIL with PyGILState_Ensure), with an mmap, page faults and a munmap of its
# frame stack: about a tenth of a lock-step robot's CPU (docs/performance.md, "Callbacks on zenoh's threads"). Compiled where _wire is built
# (a C thread-local flag), else the same Ensure through ctypes; the flag is per thread either way.
try:
    from swarm.proto._wire import pin_thread
except ImportError:  # not built (no C compiler at install)
    pin_thread = _pin_thread_ctypes


def _init_zenoh_log(zenoh) -> None:
    """zenoh's own log lines (link closed, lease expired...) on stderr: errors by default, RUST_LOG to see more."""
    global _LOG_READY
    if not _LOG_READY:
        _LOG_READY = True
        try:
            zenoh.init_log_from_env_or("error")
        except Exception:  # already initialised by the embedding program
            pass


class _ZenohInbox:
    """A ring channel of zenoh samples. wait() blocks in zenoh with the GIL released (the receiving
    thread runs no Python for these samples); wake() sends this session a local sample that carries
    the WAKE attachment, which wait() and drain() skip. Two rules: close() only from the thread that
    waits (zenoh refuses a close while recv() holds the subscriber, and the wait then never ends: wake
    it first), and no other subscriber of this session on a matching key (it would get the empty
    wake-up sample as a bad message)."""

    # this process's own marker: a wake-up never leaves the session (SESSION_LOCAL), so no other process knows it,
    # and an empty message with a marker of someone else's is a message like any other (refused and counted)
    WAKE = b"swarm-inbox-wake-" + secrets.token_hex(16).encode()

    def __init__(self, sub, session, key_expr: str, zenoh) -> None:
        self.sub, self.session, self.key_expr, self._z = sub, session, key_expr, zenoh

    def _item(self, s) -> tuple[str, bytes] | None:
        payload = s.payload.to_bytes()
        if not payload:  # a real message is never empty: only then look for the wake marker
            a = s.attachment
            if a is not None and a.to_bytes() == self.WAKE:
                return None
        return str(s.key_expr), payload

    def drain(self) -> list[tuple[str, bytes]]:
        wire = _protocol._wire  # None where it is not built (or SWARM_PURE_PYTHON)
        if wire is not None:  # the same loop compiled (swarm/proto/_wire.c): no bytecode per sample
            return wire.drain(self.sub.try_recv, self.WAKE)
        out = []
        recv = self.sub.try_recv
        while (s := recv()) is not None:
            if (item := self._item(s)) is not None:
                out.append(item)
        return out

    def wait(self) -> list[tuple[str, bytes]]:
        """Block until a sample (or wake()): it, and those behind it already here, in one call where compiled."""
        wire = _protocol._wire
        if wire is not None:
            return wire.drain(self.sub.try_recv, self.WAKE, self.sub.recv)
        first = self._item(self.sub.recv())
        return ([] if first is None else [first]) + self.drain()

    def wake(self) -> None:
        if "*" in self.key_expr:
            raise ValueError(f"wake() needs a concrete key, not {self.key_expr!r}")
        self.session.put(self.key_expr, b"", attachment=self.WAKE,
                         allowed_destination=self._z.Locality.SESSION_LOCAL)

    def close(self) -> None:
        self.sub.undeclare()


def drainer(boxes: list) -> Callable[[], list[tuple[str, bytes]]]:
    """One function that drains every inbox of `boxes` in turn, their items in that order: where all are
    zenoh inboxes and the codec is compiled, one C call for them all (swarm/proto/_wire.c), not one Python
    call and one C call an inbox (a real-time robot drains its 9 cells every period)."""
    wire = _protocol._wire
    if wire is not None and boxes and all(type(b) is _ZenohInbox for b in boxes):
        recvs, wake = tuple(b.sub.try_recv for b in boxes), _ZenohInbox.WAKE
        return lambda: wire.drain(recvs, wake)
    boxes = list(boxes)
    return lambda: [item for b in boxes for item in b.drain()]


class _Matching:
    """A publisher's matching status as its listener tells it (ZenohBus.wanted): the listener's word wins over the
    first look, whichever comes last."""

    __slots__ = ("now", "told", "lock")

    def __init__(self) -> None:
        self.now = False
        self.told = False
        self.lock = threading.Lock()

    def changed(self, status) -> None:  # on zenoh's thread
        pin_thread()
        with self.lock:
            self.now, self.told = bool(status.matching), True

    def first(self, matching: bool) -> None:
        with self.lock:
            if not self.told:
                self.now = matching


class _Undeclare:
    def __init__(self, entity) -> None:
        self.entity = entity

    def close(self) -> None:
        self.entity.undeclare()

"""The bus: key-expression matching, the in-memory bus, and the zenoh bus on a real router."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time

import pytest

from swarm.net import bus as busmod


class Events:
    """State shared with bus callbacks; waits are woken by the callbacks, never by sleeping."""

    def __init__(self) -> None:
        self.cond = threading.Condition()

    def wait_until(self, pred, timeout_s: float, what: str) -> None:
        with self.cond:
            if not self.cond.wait_for(pred, timeout=timeout_s):
                raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@pytest.mark.unit
@pytest.mark.parametrize(
    "expr, key, ok",
    [
        ("a/b/c", "a/b/c", True), ("a/*/c", "a/b/c", True), ("a/*", "a/b/c", False), ("a/**", "a/b/c", True),
        ("a/**/c", "a/c", True), ("**", "a", True), ("a/b", "a/b/c", False), ("a/*/*/7", "a/-1/2/7", True),
        ("a/*/*/7", "a/-1/2/8", False),
    ],
)
def test_matches(expr, key, ok):
    assert busmod.matches(expr, key) is ok


@pytest.mark.unit
def test_memory_bus_pubsub_tokens_and_queries():
    net = busmod.MemoryNet()
    a, b = busmod.MemoryBus(net), busmod.MemoryBus(net)
    got, alive = [], []
    sub = b.subscribe("swarm/f/robot/*/cmd", lambda k, p: got.append((k, p)))
    a.put("swarm/f/robot/3/cmd", b"x")
    a.put("swarm/f/robot/3/pose", b"y")
    assert got == [("swarm/f/robot/3/cmd", b"x")]
    sub.close()
    a.put("swarm/f/robot/3/cmd", b"z")
    assert len(got) == 1
    tok = a.token("swarm/f/alive/robot/3")
    b.watch_alive("swarm/f/alive/**", lambda k, up: alive.append((k, up)))  # history: sees the token
    tok.close()
    assert alive == [("swarm/f/alive/robot/3", True), ("swarm/f/alive/robot/3", False)]
    a.serve("swarm/f/world/obstacles", lambda k: b"obs")
    assert b.query("swarm/f/world/obstacles") == [("swarm/f/world/obstacles", b"obs")]
    a.close()
    assert b.query("swarm/f/world/obstacles") == []


@pytest.mark.unit
def test_memory_inbox_keeps_the_newest_until_drained():
    net = busmod.MemoryNet()
    a, b = busmod.MemoryBus(net), busmod.MemoryBus(net)
    box = b.inbox("swarm/f/cell/0/0/*", depth=3)
    for i in range(5):
        a.put(f"swarm/f/cell/0/0/{i}", bytes([i]))
    a.put("swarm/f/cell/1/0/9", b"elsewhere")
    assert box.drain() == [(f"swarm/f/cell/0/0/{i}", bytes([i])) for i in (2, 3, 4)]
    assert box.drain() == []
    box.close()
    a.put("swarm/f/cell/0/0/1", b"late")
    assert box.drain() == []


@pytest.mark.unit
def test_memory_put_without_loopback_skips_the_publishers_own_subscribers():
    net = busmod.MemoryNet()
    a, b = busmod.MemoryBus(net), busmod.MemoryBus(net)
    mine, theirs = a.inbox("swarm/f/cell/0/0/*"), b.inbox("swarm/f/cell/0/0/*")
    a.put("swarm/f/cell/0/0/1", b"s", loopback=False)
    assert mine.drain() == [] and theirs.drain() == [("swarm/f/cell/0/0/1", b"s")]
    a.put("swarm/f/cell/0/0/1", b"t")
    assert mine.drain() == theirs.drain() == [("swarm/f/cell/0/0/1", b"t")]


def _waiting(box) -> tuple[threading.Thread, list]:
    """box.wait() on a thread of its own; the list gets what it returned."""
    out: list = []
    th = threading.Thread(target=lambda: out.append(box.wait()), daemon=True)
    th.start()
    return th, out


def _check_wait_and_wake(box, put, key: str, timeout_s: float) -> None:
    """box.wait() returns what came, and an empty list when box.wake() is called from another thread."""
    th, out = _waiting(box)
    put(key, b"p1")
    th.join(timeout_s)
    assert out == [[(key, b"p1")]]
    th, out = _waiting(box)
    box.wake()
    th.join(timeout_s)
    assert out == [[]] and not th.is_alive()


@pytest.mark.unit
def test_memory_inbox_wait_returns_on_a_message_or_a_wake():
    net = busmod.MemoryNet()
    a, b = busmod.MemoryBus(net), busmod.MemoryBus(net)
    box = b.inbox("swarm/f/robot/1/pose", depth=4)
    _check_wait_and_wake(box, a.put, "swarm/f/robot/1/pose", 5)
    box.wake()  # a wake before the wait is not lost
    assert box.wait() == []


def _prime(box, ping, what: str) -> None:
    """Ping until a first message reaches `box`: a new subscription reaches the router asynchronously."""
    deadline = time.monotonic() + 10
    while not box.drain():
        ping()
        assert time.monotonic() < deadline, f"no message into {what}"
        time.sleep(0.02)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


_THREAD_STATE = r"""
import sys, threading, time
from swarm.net import bus as busmod

pin = sys.argv[1]
if pin == "ctypes":
    busmod.pin_thread = busmod._pin_thread_ctypes
elif pin == "none":
    busmod.pin_thread = lambda: None
endpoint = sys.argv[2]
router = busmod.ZenohBus(busmod.zenoh_config("router", listen=[endpoint]))
try:
    with busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint])) as a, \
            busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint])) as b:
        mine = threading.local()
        calls = []  # (native thread id, what this thread's local held)
        cond = threading.Condition()

        def on(k, p):
            with cond:
                calls.append((threading.get_native_id(), getattr(mine, "tid", None)))
                mine.tid = threading.get_native_id()
                cond.notify_all()

        b.subscribe("swarm/t/robot/*/cmd", on)
        deadline = time.monotonic() + 10
        while True:  # the subscription reaches the router asynchronously
            a.put("swarm/t/robot/1/cmd", b"hello", reliable=True)
            with cond:
                if cond.wait_for(lambda: bool(calls), timeout=0.05):
                    break
            assert time.monotonic() < deadline, "no message through the router"
        for i in range(100):
            a.put("swarm/t/robot/1/cmd", bytes([i]), reliable=True)
        with cond:
            # what is checked is the thread state over the callbacks that came; a CI machine under load once had 95 of
            # the 100 reliable puts in 10 s: said on stderr, and enough callbacks to judge are required
            if not cond.wait_for(lambda: len(calls) >= 101, timeout=30):
                print(f"100 messages: {len(calls) - 1} came in 30 s", file=sys.stderr)
            assert len(calls) >= 21, f"100 messages: {len(calls) - 1} came in 30 s"
            seen = list(calls)
finally:
    router.close()
print(threading.get_native_id(), *(f"{t}:{h}" for t, h in seen))
"""


def _until(told: threading.Condition, what, cond, timeout_s: float = 10.0) -> None:
    """Wait on `told` (notified by the matching listener) until cond() holds: zenoh tells a publisher of a
    subscription asynchronously, through the router. The key past the cap has no listener: it is looked at
    again at each notification and every 50 ms, up to the deadline."""
    deadline = time.monotonic() + timeout_s
    with told:
        while not cond():
            left = deadline - time.monotonic()
            assert left > 0, f"{what} within {timeout_s} s"
            told.wait(min(left, 0.05))


@pytest.mark.integration
def test_wanted_follows_the_subscribers_that_come_and_go(monkeypatch):
    """ZenohBus.wanted (the world builds a snapshot only when it is wanted) says whether a subscriber would get a
    put on a key: true as one comes, false as it goes, kept by a matching listener past the first call (one
    publisher and listener a key, no thread of their own); past WANTED keys it asks zenoh each time, with the same
    answers; a closed bus says no."""
    monkeypatch.setattr(busmod, "WANTED", 1)
    told = threading.Condition()
    heard = busmod._Matching.changed

    def changed(self, status) -> None:  # the listener's word, and a notification for the test
        heard(self, status)
        with told:
            told.notify_all()

    monkeypatch.setattr(busmod._Matching, "changed", changed)
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    router = busmod.ZenohBus(busmod.zenoh_config("router", listen=[endpoint]))
    try:
        a = busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint]))
        with busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint])) as b:
            kept, asked = "swarm/t/world/snapshot", "swarm/t/world/other"
            assert not a.wanted(kept) and not a.wanted(asked)
            assert list(a._wanted) == [kept]  # the second key is past the cap
            threads = threading.active_count()
            sub = b.subscribe("swarm/t/world/*", lambda k, p: None)
            _until(told, "a subscriber known", lambda: a.wanted(kept) and a.wanted(asked))
            sub.close()
            _until(told, "its end known", lambda: not a.wanted(kept) and not a.wanted(asked))
            assert threading.active_count() == threads
        a.close()
        assert not a.wanted(kept) and not a.wanted("swarm/t/world/never")
    finally:
        router.close()


@pytest.mark.integration
@pytest.mark.parametrize("pin", ["compiled", "ctypes", "none"])
def test_zenohs_threads_keep_their_python_thread_state_between_callbacks(pin):
    """A callback on zenoh's thread runs on the thread state the first one made (bus.pin_thread): a
    threading.local lives in the thread state, so what one callback left there is there for the next
    one on the same thread. Without the pin ("none") CPython makes a fresh state for each callback and
    each one finds nothing. In a fresh process: zenoh's threads are the process's, and other tests
    pin them."""
    if pin == "compiled" and busmod.pin_thread is busmod._pin_thread_ctypes:
        pytest.skip("swarm.proto._wire is not built")
    out = subprocess.run([sys.executable, "-c", _THREAD_STATE, pin, f"tcp/127.0.0.1:{_free_port()}"],
                         capture_output=True, text=True, timeout=90)
    assert out.returncode == 0, out.stderr
    me, *calls = out.stdout.split()
    seen = [(int(t), None if h == "None" else int(h)) for t, h in (c.split(":") for c in calls)]
    assert len(seen) >= 21 and all(t != int(me) for t, _ in seen)  # zenoh's threads, not the main one
    known = set()
    for tid, held in seen:
        if pin == "none":
            assert held is None
        else:
            assert held == (tid if tid in known else None), (tid, held)
        known.add(tid)


@pytest.mark.integration
@pytest.mark.timeout(60)
@pytest.mark.parametrize("router_filters,client_checks", [(True, True), (False, True), (True, False), (False, False)])
def test_zenoh_drops_a_payload_past_the_size_limit_on_its_way_in(router_filters, client_checks):
    """zenoh's low_pass_filter (bus.size_limits) drops a payload larger than the codec's limit before any
    subscriber sees it: at our router's ingress (also for a client without checks of its own, as swarm up's
    processes run: --router-checks), and, behind a router without the rules (somebody else's), at the
    receiving client's ingress. A payload at the limit goes through. With neither, the large one comes."""
    from swarm.proto.protocol import MAX_PAYLOAD

    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    router = busmod.ZenohBus(busmod.zenoh_config("router", listen=[endpoint]) if router_filters else
                             busmod.plain_config("router", listen=[endpoint]))
    try:
        with busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint])) as a, \
                busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint], ingress_checks=client_checks)) as b:
            box = b.inbox("swarm/t/cell/0/0/*", depth=16)
            _prime(box, lambda: a.put("swarm/t/cell/0/0/1", b"ping", reliable=True), "the inbox")
            a.put("swarm/t/cell/0/0/1", b"x" * (MAX_PAYLOAD + 1), reliable=True)
            a.put("swarm/t/cell/0/0/1", b"y" * MAX_PAYLOAD, reliable=True)
            a.put("swarm/t/cell/0/0/1", b"last", reliable=True)
            got: list = []
            while not got or got[-1][1] != b"last":  # bounded by the test's timeout
                got += box.wait()
                got += box.drain()
            sizes = [len(p) for _, p in got if p != b"ping"]
            assert sizes == ([MAX_PAYLOAD, 4] if router_filters or client_checks else [MAX_PAYLOAD + 1, MAX_PAYLOAD, 4])
            box.close()
    finally:
        router.close()


@pytest.mark.integration
@pytest.mark.timeout(60)
@pytest.mark.parametrize("cmd", ["robot", "world", "leader", "viz"])
def test_router_checks_leaves_the_ingress_checks_to_that_router_only(monkeypatch, caplog, cmd):
    """`--router-checks ZID` (what swarm up gives the processes on its own router, started with --zid ZID) opens a
    session without zenoh's size filter and wildcard guard once its router is ZID; on another router (a foreign one
    that took the port) it keeps both, and says so. Without the flag, and in a router, they are always on."""
    import json

    from swarm.cli.common import open_bus
    from swarm.cli.parser import build_parser

    made = []  # each config open_bus made: (size rules, wildcard guard)
    real = busmod.zenoh_config

    def recording(*a, **kw):
        conf = real(*a, **kw)
        down = json.loads(conf.get_json("downsampling") or "null") or []
        made.append((bool(json.loads(conf.get_json("low_pass_filter") or "null")),
                     any(d.get("id") == "swarm-wildcards" for d in down)))
        return conf

    monkeypatch.setattr(busmod, "zenoh_config", recording)
    zid, other = "a1" * 16, "b2" * 16
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    parse = build_parser().parse_args
    with open_bus(parse(["router", "--listen", endpoint, "--zid", zid]), mode="router", listen=[endpoint]) as router:
        assert str(router.session.info.zid()) == zid and made == [(True, True)]
        with open_bus(parse([cmd, "--connect", endpoint, "--router-checks", zid])):
            assert made[1:] == [(False, False)]
        with caplog.at_level("WARNING", logger="swarm"):
            with open_bus(parse([cmd, "--connect", endpoint, "--router-checks", other])):
                assert made[2:] == [(False, False), (True, True)]  # opened, found another router, opened again
        assert f"this session's router is {zid}, not it" in caplog.text
        with open_bus(parse([cmd, "--connect", endpoint])):
            assert made[4:] == [(True, True)]


@pytest.mark.unit
@pytest.mark.parametrize("bad", ["", "0abc", "ABC", "xyz", "a" * 33])
def test_a_zenoh_id_that_zenoh_would_not_write_is_refused(bad):
    from swarm.cli.parser import build_parser

    with pytest.raises(SystemExit):
        build_parser().parse_args(["robot", "--router-checks", bad])


WILDCARDS = ["swarm/t/cell/*/*/5", "swarm/t/cell/**", "swarm/**", "swarm/t/cell/0/*/5", "swarm/t/cell/$*0/0/5",
             "swarm/t/cell/0/0/*", "**", "swarm/t/**/5", "*/t/cell/0/0/5", "swarm/*/cell/0/0/5"]


@pytest.mark.integration
@pytest.mark.timeout(60)
@pytest.mark.parametrize("router_filters,client_checks", [(True, True), (False, True), (True, False)])
def test_zenoh_drops_a_put_on_a_wildcard_key_expression_before_any_subscriber(router_filters, client_checks):
    """A put on a key expression with wildcards (cell/*/*/5) reaches every subscription it intersects: a
    robot's 9 cell subscriptions got it 9 times, a flood of them stalled a lock-step swarm. zenoh's
    downsampling interceptor (bus.wildcard_guard, a rate of 0 on the key expressions only a wildcard put can
    intersect) drops it at our router's ingress (also for a client without checks of its own: --router-checks),
    and, behind a router without the rule, at the receiving client's ingress. Concrete keys go through; the
    receiver sees none of the wildcard puts."""
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    router = busmod.ZenohBus(busmod.zenoh_config("router", listen=[endpoint]) if router_filters else
                             busmod.plain_config("router", listen=[endpoint]))
    attacker_conf = busmod.plain_config("client", connect=[endpoint])  # no rule of ours on its way out
    try:
        with busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint], ingress_checks=client_checks)) as b, \
                busmod.ZenohBus(attacker_conf) as a:
            events, got = Events(), []

            def on(k, p):
                with events.cond:
                    got.append((k, p))
                    events.cond.notify_all()

            subs = [b.subscribe(f"swarm/t/cell/{cx}/{cy}/*", on) for cx in (-1, 0, 1) for cy in (-1, 0, 1)]
            deadline = time.monotonic() + 10
            while not got:  # the subscriptions reach the router asynchronously
                a.put("swarm/t/cell/0/0/5", b"ping", reliable=True)
                with events.cond:
                    events.cond.wait_for(lambda: bool(got), timeout=0.05)
                assert time.monotonic() < deadline, "no message through the router"
            for i in range(200):
                for key in WILDCARDS:
                    a.put(key, b"flood", reliable=True)
            a.put("swarm/t/cell/1/-1/6", b"last", reliable=True)
            events.wait_until(lambda: got[-1][1] == b"last", 20, "the concrete put after the flood")
            assert {k for k, p in got} == {"swarm/t/cell/0/0/5", "swarm/t/cell/1/-1/6"}
            assert not any(p == b"flood" for _, p in got)
            for sub in subs:
                sub.close()
    finally:
        router.close()


@pytest.mark.integration
@pytest.mark.timeout(60)
def test_zenoh_bus_through_a_router():
    """Two clients of a router in this process: pub/sub, BLOCK puts, liveliness, queryable."""
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    router = busmod.ZenohBus(busmod.zenoh_config("router", listen=[endpoint]))
    try:
        with busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint])) as a, \
                busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint])) as b:
            got: list[tuple[str, bytes]] = []
            alive: dict[str, bool] = {}
            ev = Events()

            def on(k, p):
                with ev.cond:
                    got.append((k, p))
                    ev.cond.notify_all()

            def on_alive(k, up):
                with ev.cond:
                    alive[k] = up
                    ev.cond.notify_all()

            b.subscribe("swarm/t/robot/*/cmd", on)
            b.watch_alive("swarm/t/alive/**", on_alive)
            tok = a.token("swarm/t/alive/robot/1")
            ev.wait_until(lambda: alive.get("swarm/t/alive/robot/1") is True, 10, "the token to appear")
            # the subscription reaches the router asynchronously: repeat the first put until one arrives
            deadline = time.monotonic() + 10
            while True:
                a.put("swarm/t/robot/1/cmd", b"hello", reliable=True)
                with ev.cond:
                    if ev.cond.wait_for(lambda: bool(got), timeout=0.05):
                        break
                assert time.monotonic() < deadline, "no message through the router"
            with ev.cond:
                got.clear()
            for i in range(200):
                a.put("swarm/t/robot/1/cmd", i.to_bytes(2, "big"), reliable=True)
            ev.wait_until(lambda: len(got) >= 200, 10, "200 reliable messages")
            assert [int.from_bytes(p, "big") for _, p in got[:200]] == list(range(200))
            a.serve("swarm/t/world/obstacles", lambda k: b"obstacles!")
            replies = []
            deadline = time.monotonic() + 10
            while not replies and time.monotonic() < deadline:
                replies = b.query("swarm/t/world/obstacles", timeout_s=1.0)
            assert replies == [("swarm/t/world/obstacles", b"obstacles!")]
            # an inbox: samples wait in zenoh until drained, the newest `depth`, in order
            box = b.inbox("swarm/t/cell/0/0/*", depth=4)
            _prime(box, lambda: a.put("swarm/t/cell/0/0/1", b"ping", reliable=True), "the inbox")
            a.put("swarm/t/cell/0/0/1", b"sync", reliable=True)
            seen: list = []
            while b"sync" not in [p for _, p in seen]:  # bounded by the test's timeout
                seen += box.wait()
            box.drain()
            for i in range(10):
                a.put("swarm/t/cell/0/0/2", bytes([i]), reliable=True)
            a.put("swarm/t/cell/0/0/3", b"last", reliable=True)
            got_box: list = []
            while not got_box or got_box[-1][1] != b"last":  # bounded by the test's timeout
                got_box += box.wait()
                got_box += box.drain()
            assert got_box[-1] == ("swarm/t/cell/0/0/3", b"last")
            assert [p for _, p in got_box[:-1]] == sorted(p for _, p in got_box[:-1])  # in order, oldest dropped
            box.close()
            # wait() blocks in zenoh until a sample comes; wake() (a session-local sample) returns it empty
            pose = b.inbox("swarm/t/robot/1/pose", depth=4)
            _prime(pose, lambda: a.put("swarm/t/robot/1/pose", b"ping", reliable=True), "the pose inbox")
            _check_wait_and_wake(pose, lambda k, p: a.put(k, p, reliable=True), "swarm/t/robot/1/pose", 10)
            a.put("swarm/t/robot/1/pose", b"p2", reliable=True)
            assert pose.wait() == [("swarm/t/robot/1/pose", b"p2")]  # the wake left nothing behind
            # an empty message from elsewhere with a marker not this process's own (a forger cannot know it: a wake-up
            # never leaves its session) is a message, which its receiver refuses and counts, not a silent wake-up
            a.session.put("swarm/t/robot/1/pose", b"", attachment=b"swarm-inbox-wake")
            assert pose.wait() == [("swarm/t/robot/1/pose", b"")]
            with pytest.raises(ValueError):
                box.wake()  # a wildcard inbox cannot be woken
            pose.close()
            # loopback=False: a put reaches the other sessions, not this session's own subscribers
            mine, theirs = a.inbox("swarm/t/cell/5/5/*"), b.inbox("swarm/t/cell/5/5/*")
            _prime(theirs, lambda: a.put("swarm/t/cell/5/5/1", b"ping", loopback=False), "the cell inbox")
            a.put("swarm/t/cell/5/5/1", b"remote only", reliable=True, loopback=False)
            a.put("swarm/t/cell/5/5/1", b"everyone", reliable=True)
            seen: list = []
            while b"everyone" not in seen:
                seen += [p for _, p in theirs.wait()]
            assert seen[-2:] == [b"remote only", b"everyone"]
            assert [p for _, p in mine.wait()] == [b"everyone"]  # none of the pings, nor "remote only"
            mine.close()
            theirs.close()
            tok.close()
            ev.wait_until(lambda: alive.get("swarm/t/alive/robot/1") is False, 10, "the token to go")
    finally:
        router.close()


@pytest.mark.integration
@pytest.mark.timeout(60)
def test_hinted_keys_still_deliver_and_the_hints_stay_bounded(monkeypatch):
    """ZenohBus.hint declares a key this session receives through a wildcard subscription (its route is
    then resolved once). Samples on hinted keys, on keys hinted before the bound made it start over, and on
    keys never hinted all arrive, in order; the session never holds more than KEY_HINTS declarations."""
    monkeypatch.setattr(busmod, "KEY_HINTS", 4)
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    router = busmod.ZenohBus(busmod.zenoh_config("router", listen=[endpoint]))
    try:
        with busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint])) as a, \
                busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint])) as b:
            box = b.inbox("swarm/t/cell/2/3/*", depth=64)
            _prime(box, lambda: a.put("swarm/t/cell/2/3/0", b"ping", reliable=True), "the cell inbox")
            for j in range(10):
                b.hint(f"swarm/t/cell/2/3/{j}")
                b.hint(f"swarm/t/cell/2/3/{j}")  # again: nothing more
                assert len(b._hints) <= 4
            assert sorted(b._hints) == [f"swarm/t/cell/2/3/{j}" for j in (8, 9)]  # started over at the 9th
            sent = [(f"swarm/t/cell/2/3/{j}", bytes([j, i])) for i in range(3) for j in range(12)]
            for key, p in sent:
                a.put(key, p, reliable=True)
            got: list = []
            while len(got) < len(sent):  # bounded by the test's timeout
                got += [m for m in box.wait() + box.drain() if m[1] != b"ping"]
            assert got == sent
            box.close()
        assert b._hints == {}  # closing the session let them go with it
    finally:
        router.close()


@pytest.mark.integration
@pytest.mark.timeout(60)
def test_a_drainer_drains_every_inbox_in_turn_in_one_call():
    """bus.drainer(boxes): every inbox's items, inbox after inbox, each in its own order. Over zenoh inboxes it
    is one compiled call (where _wire is built), over others their drain()s."""
    net = busmod.MemoryNet()
    m, feed = busmod.MemoryBus(net), busmod.MemoryBus(net)
    boxes = [m.inbox("swarm/t/cell/0/0/*"), m.inbox("swarm/t/cell/1/0/*")]
    for key in ("swarm/t/cell/1/0/5", "swarm/t/cell/0/0/2", "swarm/t/cell/1/0/6"):
        feed.put(key, key[-1:].encode())
    drain = busmod.drainer(boxes)
    assert drain() == [("swarm/t/cell/0/0/2", b"2"), ("swarm/t/cell/1/0/5", b"5"), ("swarm/t/cell/1/0/6", b"6")]
    assert drain() == []
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    router = busmod.ZenohBus(busmod.zenoh_config("router", listen=[endpoint]))
    try:
        with busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint])) as a, \
                busmod.ZenohBus(busmod.zenoh_config("client", connect=[endpoint])) as b:
            boxes = [b.inbox(f"swarm/t/cell/{c}/0/*", depth=16) for c in range(3)]
            done = b.inbox("swarm/t/robot/1/pose", depth=4)
            _prime(done, lambda: a.put("swarm/t/robot/1/pose", b"ping", reliable=True), "the pose inbox")
            for c, box in enumerate(boxes):
                _prime(box, lambda c=c: a.put(f"swarm/t/cell/{c}/0/9", b"ping", reliable=True), f"cell {c}")

            def settle() -> None:  # everything a sent before this is in b's inboxes (one link, in order)
                a.put("swarm/t/robot/1/pose", b"done", reliable=True)
                while [p for _, p in done.wait() + done.drain()][-1:] != [b"done"]:  # bounded by the test's timeout
                    pass

            drain = busmod.drainer(boxes)
            settle()
            drain()  # the pings still under way when each inbox was primed
            assert drain() == []
            sent = [(f"swarm/t/cell/{c}/0/{j}", bytes([c, j])) for j in range(3) for c in (2, 0, 1)]
            for key, p in sent:
                a.put(key, p, reliable=True)
            settle()
            assert drain() == sorted(sent, key=lambda m: m[1][0])  # box by box, each in the order sent
            assert drain() == []
            for p in (b"a", b"b", b"c"):
                a.put("swarm/t/cell/0/0/4", p, reliable=True)
            settle()
            # an inbox's wait(): the sample it woke for and those already behind it, in order, in one call
            assert boxes[0].wait() == [("swarm/t/cell/0/0/4", p) for p in (b"a", b"b", b"c")]
            assert drain() == []
            done.close()
    finally:
        router.close()

"""`swarm router` refuses an oversized message before it buffers it, and still carries the largest legitimate one.

zenoh's low_pass_filter (swarm.net.bus.size_limits) sees a message only once the receiving link has put its
fragments back together; swarm.net.bus.zenoh_config stops that defragmentation at the codec's large limit
(transport/link/rx/max_message_size), so an attacker's 64 MiB puts cost the router at most that much at a time
and leave it about as large as before. The router runs as the product runs it (python -m swarm.cli router, its
own process group, killed by PID); the attacker is a plain zenoh client: no size filter, zenoh's 1 GiB limit.
Waits are on events with deadlines, never sleeps.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from swarm.launch.child import stop_group
from swarm.net.bus import ZenohBus, plain_config, zenoh_config
from swarm.proto import keys, protocol
from tests.integration.helpers import wait_until

ROOT = Path(__file__).resolve().parents[2]
FLEET = "mem"
WAIT_S = 10.0  # the longest any one wait may take
PUTS, PUT_MIB = 12, 64  # the attack: 12 puts of 64 MiB (6-12 s here)
GROWTH_MIB = 64  # what the attack may cost the router, at its peak and after


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def mib(pid: int, field: str) -> float:
    """VmRSS (resident now) or VmHWM (the peak so far) of a process, in MiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no {field} in /proc/{pid}/status")


class Seen:
    """Payloads a subscriber received, in order; wait_for blocks on a condition."""

    def __init__(self) -> None:
        self.items: list[bytes] = []
        self.cond = threading.Condition()

    def add(self, payload: bytes) -> None:
        with self.cond:
            self.items.append(payload)
            self.cond.notify_all()

    def wait_for(self, pred, what: str, timeout_s: float = WAIT_S) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: pred(self.items), timeout=timeout_s)


def until_through(put, seen: Seen, tag: bytes, what: str) -> None:
    """put(tag) until it reaches the subscriber: a put before the router knows the subscription is lost."""
    deadline = time.monotonic() + WAIT_S
    while True:
        put(tag)
        if seen.wait_for(lambda items: tag in items, what, 0.2):
            return
        assert time.monotonic() < deadline, f"{what}: {tag!r} never reached the subscriber"


@pytest.fixture
def router(tmp_path):
    """(endpoint, Popen) of `swarm router` on a free loopback port, up: its liveliness token answers."""
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open(tmp_path / "router.log", "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", "router", "--listen", endpoint, "--fleet", FLEET,
                                 "--log-level", "warning"], stdin=subprocess.DEVNULL, stdout=log,
                                stderr=subprocess.STDOUT, process_group=0, cwd=ROOT)
    try:
        deadline = time.monotonic() + WAIT_S

        def opened():  # the router opens its port asynchronously: a client session opens once it does
            assert proc.poll() is None, (tmp_path / "router.log").read_text(errors="replace")
            try:
                return zenoh.open(zenoh_config("client", connect=[endpoint]))
            except Exception:
                return None

        probe = wait_until(opened, WAIT_S, f"a router on {endpoint}", every_s=0.05)
        try:
            while not list(probe.liveliness().get(keys.alive(FLEET, "router"), timeout=1.0)):
                assert time.monotonic() < deadline, "the router's liveliness token did not appear"
        finally:
            probe.close()
        yield endpoint, proc
    finally:
        stop_group(proc)




@pytest.mark.integration
@pytest.mark.timeout(60)
def test_oversized_puts_cost_the_router_neither_their_size_nor_memory_it_keeps(router):
    """12 puts of 64 MiB on a robot's command key from a client without a size filter: no subscriber gets
    one, the router's resident memory grows less than 64 MiB at its peak (it would hold a whole 64 MiB
    message to defragment it) and after, and the attacker's link stays open (the small put that follows
    on the same session arrives; its liveliness token never went down)."""
    import zenoh

    endpoint, proc = router
    key = keys.robot_cmd(FLEET, 3)
    seen, tokens = Seen(), Seen()
    with ZenohBus(zenoh_config("client", connect=[endpoint])) as robot:
        robot.subscribe(key, lambda k, p: seen.add(p if len(p) < 64 else len(p).to_bytes(8, "big")))
        robot.session.liveliness().declare_subscriber(
            "attacker/alive", lambda s: tokens.add(b"up" if s.kind == zenoh.SampleKind.PUT else b"down"), history=True)
        attacker = zenoh.open(plain_config("client", connect=[endpoint]))
        try:
            token = attacker.liveliness().declare_token("attacker/alive")  # kept: a dropped token is undeclared
            assert tokens.wait_for(lambda items: b"up" in items, "the attacker's token"), "the attacker's token"
            pub = attacker.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)  # every fragment
            until_through(pub.put, seen, b"warm-up", "a small put")
            before, peak_before = mib(proc.pid, "VmRSS"), mib(proc.pid, "VmHWM")
            big = bytes(PUT_MIB << 20)
            for _ in range(PUTS):
                pub.put(big)
            pub.put(b"after")  # behind the big ones on the same link: when it arrives the router handled them
            assert seen.wait_for(lambda items: b"after" in items, "the put after", 30), \
                "the small put after the big ones never came: the attacker's link was closed?"
            after, peak = mib(proc.pid, "VmRSS"), mib(proc.pid, "VmHWM")
            assert [p for p in seen.items if p not in (b"warm-up", b"after")] == []  # not one big payload
            assert b"down" not in tokens.items
            token.undeclare()
        finally:
            attacker.close()
    assert proc.poll() is None
    print(f"router RSS {before:.0f} MiB before {PUTS} puts of {PUT_MIB} MiB, {after:.0f} MiB after, "
          f"peak {peak:.0f} MiB (peak before {peak_before:.0f} MiB)")
    assert peak - before < GROWTH_MIB, f"the router's peak went from {before:.0f} to {peak:.0f} MiB"
    assert after - before < GROWTH_MIB, f"the router's RSS went from {before:.0f} to {after:.0f} MiB"


@pytest.mark.integration
@pytest.mark.timeout(60)
def test_the_largest_legitimate_messages_still_go_through_the_router(router):
    """A snapshot-key payload at the codec's large limit (16 MiB), and a real snapshot of 2000 robots, go
    from a swarm client through the router to a swarm subscriber whole; one byte more does not (the
    low_pass_filter's rule, behind the transport's larger max_message_size)."""
    endpoint, _proc = router
    key = keys.world_snapshot(FLEET)
    seen = Seen()
    snap = protocol.Snapshot(t=123456.789, seq=2**31, robots=tuple(
        protocol.RobotSnap(i, -123456.7 + i * 1e-3, 98765.4321, 3.4, -99.9, 99.9, True, False) for i in range(2000)))
    real = protocol.encode(snap)
    with ZenohBus(zenoh_config("client", connect=[endpoint])) as world, \
            ZenohBus(zenoh_config("client", connect=[endpoint])) as viewer:
        viewer.subscribe(key, lambda k, p: seen.add(p))
        until_through(lambda p: world.put(key, p, reliable=True), seen, b"ping", "a small snapshot-key put")
        world.put(key, bytes(protocol.MAX_LARGE_PAYLOAD + 1), reliable=True)
        world.put(key, b"\x07" * protocol.MAX_LARGE_PAYLOAD, reliable=True)
        world.put(key, real, reliable=True)
        world.put(key, b"last", reliable=True)
        assert seen.wait_for(lambda items: b"last" in items, "the last put", 30), "the last put never came"
    got = [p for p in seen.items if p != b"ping"]
    assert [len(p) for p in got] == [protocol.MAX_LARGE_PAYLOAD, len(real), 4]
    assert got[0] == b"\x07" * protocol.MAX_LARGE_PAYLOAD
    assert protocol.decode(got[1], kind="snapshot") == snap


@pytest.mark.unit
def test_the_router_trims_its_heap_while_memory_is_up_and_takes_memory_in_use_as_its_base(monkeypatch):
    """swarm.cli.router.HeapTrim, on a made-up resident size: no trim below base + TRIM_STEP; a trim at every
    look above it while trims free memory; after TRIM_IDLE trims in a row that freed nothing, what is
    resident is the base (no trim at every look for memory in use)."""
    from swarm.cli import router as r

    resident = [100 << 20]
    floor = [100 << 20]  # what a trim cannot give back: in use
    trims: list[int] = []

    def trim(pad: int) -> int:
        trims.append(pad)
        resident[0] = max(resident[0] - (10 << 20), floor[0])
        return 1

    monkeypatch.setattr(r, "_malloc_trim", lambda: trim)
    monkeypatch.setattr(r.HeapTrim, "rss", lambda self: resident[0])
    t = r.HeapTrim()
    resident[0] += r.TRIM_STEP - 1
    t.check()
    assert trims == []
    resident[0] = 130 << 20  # an attack's buffers, freed: each trim gives 10 MiB back
    for _ in range(3):
        t.check()
    assert len(trims) == 3 and resident[0] == 100 << 20
    t.check()
    assert len(trims) == 3  # back at the base
    floor[0] = resident[0] = 120 << 20  # more memory in use (more clients): nothing to give back
    for _ in range(r.TRIM_IDLE + 5):
        t.check()
    assert len(trims) == 3 + r.TRIM_IDLE and t.base == 120 << 20

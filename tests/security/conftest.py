"""A router and its clients in this test process, on a free loopback port: `secure` (mutual TLS,
the access control generated from the role table, each client with its identity's certificate) or
`open` (plain TCP, no access control: the network without --secure).

    with Net(fleet_dir, secure_=True) as net:
        world = net.bus("world"); r3 = net.bus("robot", 3)
        seen = Seen(); world.subscribe(keys.robot_any(FLEET, "cmd"), seen.add)
    with Net(fleet_dir, secure_=True, told=True) as net:
        net.auditor                       # everything the router let in (a subscriber on the router itself)

Waits are on events with deadlines (Seen.wait_for), never sleeps; every session is closed on exit.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import pytest

from swarm.net import secure
from swarm.net.bus import ZenohBus, zenoh_config
from swarm.proto import keys

FLEET = "sec"
ROBOTS = 6
WAIT_S = 5.0  # the longest any one wait may take


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def fleet_dir(tmp_path_factory) -> Path:
    """A fleet directory of ROBOTS robots (its port is replaced per test)."""
    d = tmp_path_factory.mktemp("sec") / "fleet"
    secure.init_fleet(d, ROBOTS, FLEET)
    return d


@pytest.fixture(scope="session")
def other_dir(tmp_path_factory) -> Path:
    """Another fleet directory of the same fleet name: another CA."""
    d = tmp_path_factory.mktemp("other") / "fleet"
    secure.init_fleet(d, ROBOTS, FLEET)
    return d


class Seen:
    """(key, payload) pairs a callback received, in order; wait_for blocks on a condition."""

    def __init__(self) -> None:
        self.items: list[tuple[str, bytes]] = []
        self.cond = threading.Condition()

    def add(self, *item) -> None:
        """(key, payload), or any tuple: (who, key, payload)."""
        with self.cond:
            self.items.append(tuple(bytes(x) if isinstance(x, (bytes, bytearray, memoryview)) else x for x in item))
            self.cond.notify_all()

    def alive(self, key: str, up: bool) -> None:
        self.add(key, b"up" if up else b"down")

    def wait_for(self, pred, what: str, timeout_s: float = WAIT_S) -> list[tuple[str, bytes]]:
        with self.cond:
            if not self.cond.wait_for(lambda: pred(self.items), timeout=timeout_s):
                raise AssertionError(f"timed out after {timeout_s} s waiting for {what}; saw {self.items}")
            return list(self.items)

    def retry(self, action, pred, what: str, timeout_s: float = WAIT_S, every_s: float = 0.2) -> list:
        """action() until pred(items) holds, waiting up to every_s for a message after each try: a
        put before the router knows of a fresh subscription is lost, the next one arrives."""
        deadline = time.monotonic() + timeout_s
        while True:
            action()
            left = deadline - time.monotonic()
            with self.cond:
                if self.cond.wait_for(lambda: pred(self.items), timeout=max(0.0, min(every_s, left))):
                    return list(self.items)
            if left <= 0:
                raise AssertionError(f"timed out after {timeout_s} s waiting for {what}; saw {self.items}")

    def wait_key(self, key: str, payload: bytes | None = None, timeout_s: float = WAIT_S) -> list[tuple[str, bytes]]:
        return self.wait_for(lambda items: any(k == key and (payload is None or p == payload) for k, p in items),
                             f"{key} {payload!r}", timeout_s)


def told(acl: dict) -> dict:
    """The generated access control plus one rule: every client is told of every subscription.

    A zenoh client does not send a put that no subscription it knows of wants, and the generated
    rules tell a client only of the subscriptions to what it may put. So robot 3's forged
    leader/ref might never leave robot 3 at all, and a test could not tell the router's rule from
    the client's politeness. Told of every subscription, the attacker's client sends everything,
    and only the router's ingress rules can stop it (they are unchanged: this rule lets nothing in
    or out but subscription declarations)."""
    acl = json.loads(json.dumps(acl))
    acl["rules"].append({"id": "told", "permission": "allow", "flows": ["egress"], "messages": ["declare_subscriber"],
                         "key_exprs": ["**"]})
    acl["subjects"].append({"id": "everyone"})  # no property: every client
    acl["policies"].append({"id": "told", "rules": ["told"], "subjects": ["everyone"]})
    return acl


class Net:
    """A router (a zenoh session in router mode) and client buses on one fresh loopback port."""

    def __init__(self, fleet_dir: Path, secure_: bool, told: bool = False) -> None:
        self.dir, self.secure, self.told = fleet_dir, secure_, told
        self.port = free_port()
        self.buses: list[ZenohBus] = []
        self.router: ZenohBus | None = None
        self.auditor = Seen()

    @property
    def endpoint(self) -> str:
        return f"{'tls' if self.secure else 'tcp'}/127.0.0.1:{self.port}"

    def __enter__(self) -> "Net":
        if self.secure:
            conf = secure.router_config(self.dir, listen=[self.endpoint])
            if self.told:
                conf.insert_json5("access_control", json.dumps(told(json.loads(conf.get_json("access_control")))))
            conf = zenoh_config("router", base=conf)  # our settings on top, as `swarm router --secure` has them
        else:
            conf = zenoh_config("router", listen=[self.endpoint])
        self.router = ZenohBus(conf)
        # the router's own session is not a client of itself: no rule applies to it, so (when the
        # clients are told of its subscription: `told`) it sees every message the router let in
        self.router.subscribe(f"{keys.base(FLEET)}/**", self.auditor.add)
        return self

    def config(self, role: str, i: int = 0, directory: Path | None = None):
        if self.secure:
            conf = secure.secure_config(directory or self.dir, role, i if role == "robot" else None,
                                        connect=[self.endpoint])
            return zenoh_config("client", base=conf)  # our settings on top, as every process has them
        return zenoh_config("client", connect=[self.endpoint])

    def bus(self, role: str, i: int = 0, directory: Path | None = None) -> ZenohBus:
        b = ZenohBus(self.config(role, i, directory))
        self.buses.append(b)
        return b

    def __exit__(self, *exc) -> None:
        for b in self.buses[::-1]:
            b.close()
        if self.router is not None:
            self.router.close()


def tokens_at_router(net: Net) -> set[str]:
    """The liveliness tokens the router holds, asked from its own session (no rule filters that)."""
    return {str(r.ok.key_expr) for r in net.router.session.liveliness().get(f"{keys.base(FLEET)}/**", timeout=2.0)
            if r.ok is not None}

"""`--id auto`: the world hands robot ids out, one claim at a time (docs/deploy.md).

    table = ClaimTable(robots=7)                   # pure: the rules below, under a lock
    table.claim("host-3", now) -> Claim            # the lowest free id (granted), or why not
    table.alive(3, True)                           # robot 3's liveliness token appeared: its claim is final
    server = ClaimServer(bus, fleet, robots=7)     # serves world/claim/<key> from a table, watches alive/robot/*
    i = request_id(bus, fleet, "host-3", 60.0)     # a robot's side: ask until the world answers

The rules. A robot started without an id asks the world's queryable `world/claim/<claim key>`; the
world answers one query at a time (the table's lock), so two robots never get the same id.
- An id is taken while a robot's liveliness token for it is alive (whoever started it), or while a
  claim on it is provisional: granted less than `provisional_s` ago and its token not seen yet.
  A claim becomes final when its robot's token appears, and ends when that token goes away (the
  robot died or was cut off, one zenoh lease after: about a second); a provisional claim whose token
  never came ends after `provisional_s`. A robot must declare its token within that time.
- The same claim key gets the same answer while its claim holds (a lost reply costs nothing: ask
  again), and its last id again later if that id is free then: give a robot a stable key (its
  hostname: a restarted container keeps it) and it comes back as itself.
- Otherwise the lowest free id, preferring ids no other key held last; none free: refused, with
  the reason (every id of the run is taken).
Claims are refused to ROS 2 robots and under --secure (hardware and certificates fix the id): the
command line does that before asking.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
import uuid

from swarm.core.clock import WALL
from swarm.proto import keys, protocol
from swarm.proto.protocol import Claim, ProtocolError
from swarm.core.errors import SwarmError

log = logging.getLogger("swarm.claims")

PROVISIONAL_S = 10.0  # s: a granted id waits this long for its robot's liveliness token
HOSTNAME = "@hostname"  # --claim-key @hostname: this machine's (container's) host name


class ClaimRefused(SwarmError, RuntimeError):
    """The world refused the claim (every id is taken); the message says why."""


class NoClaimAnswer(SwarmError, RuntimeError):
    """No world answered the claim in time."""


class ClaimTable:
    """Which claim key holds which id (thread-safe; times are monotonic seconds the caller gives)."""

    def __init__(self, robots: int, provisional_s: float = PROVISIONAL_S) -> None:
        if isinstance(robots, bool) or not isinstance(robots, int) or not 1 <= robots <= protocol.MAX_ROBOTS:
            raise ValueError(f"robots must be an int in 1..{protocol.MAX_ROBOTS}, got {robots!r}")
        if not provisional_s > 0:
            raise ValueError(f"provisional_s must be > 0, got {provisional_s!r}")
        self.robots, self.provisional_s = robots, provisional_s
        self.lock = threading.Lock()
        self.holder: dict[int, str] = {}  # id -> the claim key holding it now
        self.granted_at: dict[int, float] = {}  # id -> when its claim was granted (provisional until confirmed)
        self.confirmed: set[int] = set()  # ids whose claim's token appeared
        self.tokens: set[int] = set()  # ids with a live robot token (claimed or not)
        self.last: dict[str, int] = {}  # claim key -> the id it held last
        self.granted = self.refused = 0

    def claim(self, key: str, now: float) -> Claim:
        """Answer claim key `key` at time `now` [s] (see the module's rules)."""
        keys.check_claim(key)
        with self.lock:
            self._expire(now)
            for i, k in self.holder.items():
                if k == key:  # asked again (a lost reply, a quick restart): the same id
                    if i not in self.confirmed:
                        self.granted_at[i] = now
                    return Claim(i, key, True, self.robots, "")
            free = [i for i in range(self.robots) if i not in self.holder and i not in self.tokens]
            if not free:
                self.refused += 1
                waiting = sum(1 for i in self.holder if i not in self.confirmed)
                return Claim(0, key, False, self.robots, f"every id of the run is taken (ids 0..{self.robots - 1}: "
                             f"{len(self.tokens)} robots alive, {waiting} claims waiting for their robot's token)")
            mine = self.last.get(key)
            if mine in free:
                i = mine
            else:
                others = set(v for k, v in self.last.items() if k != key)
                i = min((j for j in free if j not in others), default=free[0])
            self.holder[i] = key
            self.granted_at[i] = now
            self.confirmed.discard(i)
            if i in self.tokens:
                self.confirmed.add(i)
            self.last[key] = i
            self.granted += 1
            return Claim(i, key, True, self.robots, "")

    def alive(self, i: int, up: bool) -> None:
        """Robot i's liveliness token appeared (up) or went away."""
        if not 0 <= i < self.robots:
            return
        with self.lock:
            if up:
                self.tokens.add(i)
                if i in self.holder:
                    self.confirmed.add(i)
            else:
                self.tokens.discard(i)
                if i in self.holder and i in self.confirmed:
                    self._release(i)

    def _expire(self, now: float) -> None:
        for i in [i for i in self.holder if i not in self.confirmed]:
            if now - self.granted_at[i] > self.provisional_s:
                log.warning("claim of id %d by %r lapsed: no liveliness token within %g s", i, self.holder[i],
                            self.provisional_s)
                self._release(i)

    def _release(self, i: int) -> None:
        self.holder.pop(i)
        self.granted_at.pop(i, None)
        self.confirmed.discard(i)

    def holders(self) -> dict[int, tuple[str, bool]]:
        """id -> (claim key, final) for every claim that holds now."""
        with self.lock:
            return {i: (k, i in self.confirmed) for i, k in sorted(self.holder.items())}


class ClaimServer:
    """The world's side: serves world/claim/<key> from a ClaimTable, which watches the robots' tokens."""

    def __init__(self, bus, fleet: str, robots: int, provisional_s: float = PROVISIONAL_S, clock=WALL) -> None:
        self.bus, self.fleet, self.clock = bus, keys.check_fleet(fleet), clock
        self.table = ClaimTable(robots, provisional_s)
        self.bad = protocol.BadMessages(log)
        self._handles: list = []

    def start(self) -> None:
        """Watch the robots' tokens (the current ones first), then answer claims."""
        self._handles.append(self.bus.watch_alive(keys.alive_any(self.fleet, "robot"), self._on_alive))
        self._handles.append(self.bus.serve(keys.world_claim_any(self.fleet), self._answer))

    def _on_alive(self, key: str, up: bool) -> None:
        k = keys.parse(key)
        if k is not None and k.kind == "alive" and k.role == "robot" and k.id is not None:
            self.table.alive(k.id, up)

    def _answer(self, key: str) -> bytes | None:
        k = keys.parse(key)
        if k is None or k.kind != "claim" or k.claim is None or k.fleet != self.fleet:
            self.bad.reject(key, ProtocolError("not a claim key of this fleet"))
            return None
        c = self.table.claim(k.claim, self.clock.monotonic())
        if c.granted:
            log.info("claim %r: id %d", c.claim, c.id)
        else:
            log.warning("claim %r refused: %s", c.claim, c.reason)
        return protocol.encode(c)

    def close(self) -> None:
        for h in self._handles[::-1]:
            h.close()
        self._handles.clear()


def claim_key(given: str | None) -> str:
    """The claim key of a robot: `given` (HOSTNAME: this machine's host name), or a new random one
    (each start then takes a fresh id). KeyError_ (swarm.proto.keys) for a key that cannot be one."""
    if given is None:
        return f"auto-{uuid.uuid4().hex[:16]}"
    if given == HOSTNAME:
        return keys.check_claim(socket.gethostname()[:64])
    return keys.check_claim(given)


def request_id(bus, fleet: str, key: str, timeout_s: float, stop: threading.Event | None = None,
               retry_s: float = 0.5) -> int:
    """Ask the world for an id under claim key `key` until it answers (NoClaimAnswer after timeout_s,
    ClaimRefused if it refuses). The same key gets the same answer, so asking again is safe."""
    topic = keys.world_claim(fleet, key)
    end = time.monotonic() + timeout_s
    last = "no reply"
    while True:
        left = end - time.monotonic()
        for rkey, payload in bus.query(topic, timeout_s=max(0.05, min(1.0, left))):
            try:
                c = protocol.decode(payload, "claim")
            except ProtocolError as e:
                last = f"bad reply on {rkey}: {e}"
                continue
            if c.claim != key:
                last = f"a reply for claim key {c.claim!r}"
                continue
            if not c.granted:
                raise ClaimRefused(f"the world refused claim {key!r}: {c.reason}")
            return c.id
        if time.monotonic() >= end or (stop is not None and stop.is_set()):
            raise NoClaimAnswer(f"no answer to claim {key!r} on {topic} within {timeout_s:g} s ({last}); is a world "
                                "running on this fleet and router?")
        if stop is not None:
            stop.wait(retry_s)
        else:
            time.sleep(retry_s)

"""A hostile network against a running `swarm up`: malformed and out-of-window messages on every key.

    python bench/hostile.py [--robots 7] [--duration 200] [--rate 2000] [--attack-s 20] [--out DIR]
    python bench/hostile.py --floods [--robots 7] [--duration 60]

--floods: instead of the mixed attack below, one flood after the other on the running lock-step swarm, each
measured on its own (the robots' CPU and the world's missed commands over the flood and 2 s after it, against
as long a quiet stretch just before): 20 000 puts of one robot's state on the wildcard cell key
cell/*/*/<id>, 20 000 states on 20 000 distinct wildcard keys cell/*/*/<j>, 20 000 states of the robots
with the next tick's seq and a forged t (1e8) on the cell keys they are heard on, and 12 payloads of 64 MiB
on a robot's command key (the router's resident memory before and after). Then the run's checks: exit 0,
no collision, no missed command, the trace equal to swarm sim's.

Starts a lock-step `swarm up --robots N --duration D --no-viz --trace --metrics --log-dir` on a free
loopback port, waits on the world's progress messages (world/progress) until the run is past tick
START_TICK, then sends `--rate` messages a second for `--attack-s` seconds from its own zenoh client
session to every key of the running swarm: leader/ref, every robot's pose, cmd and status, the cell
keys of every robot's neighbourhood, world/clock, world/progress, world/run, world/snapshot and
estop. Only messages that the receivers must refuse: garbage bytes, an unhashable kind, a kind
that is a map, another protocol version, numbers beyond the physical bounds (vel 1.7e308, x = 1e7),
sequence numbers and times that jump (seq 2^53 - 1, a clock of seq 10^9, t = 1e8), times that are
not their seq's tick (t != seq x dt: forged, bad in lock-step), messages older than what the receivers
have (stale), states with ids outside the scenario or an id that differs from the key's, a cell key whose last chunk is no id, and payloads beyond zenoh's size limits (100 kB
on a small key, 10 MB on a cell key, 20 MB on world/snapshot). On world/run, world/progress and
estop it sends malformed messages only: a well-formed run announcement starts a new run and a
well-formed emergency stop stops every robot, by design (docs/security.md).

The attacker is a client that does not filter its own traffic (zenoh's size filter is off in its
session), so oversized payloads reach the router, whose filter drops them. It sends reliably
(congestion control BLOCK), so nothing it counts as sent is lost on its own side. It keeps, per key
and per receiver, what it sent and what each receiver must make of it: "bad" (malformed, beyond a
bound, a jump: BadMessages.count), "stale" (older than the receiver's window: BadMessages.stale),
"zenoh" (beyond the size filter: never delivered), or "uncounted" (a receiver that keeps no counter it
reports: the run followers, nobody at all on world/snapshot). A state carrying the receiver's own id
is bad (an impostor: a robot never hears its own).

A cell key reaches every robot subscribed to that cell (its 3 x 3 block, and for one tick the block
it left). The bench follows every robot's cell from its pose (it subscribes to robot/*/pose) and
attacks a cell only when every robot's membership is certain: each robot's cells of the last
CELL_STABLE_S seconds are all within one cell of it (subscribed) or all three or more away (not),
and its position is CELL_MARGIN_M inside (or outside) that reach, decided at the moment each
message is sent.

Then it checks: `swarm up` exited 0 with metrics failure null; no collision, no missed command, no
lock-step overrun; the run outlasted the attack; the trace equals `swarm sim`'s step for step
(largest difference 0); and every receiver's counters equal what was sent to it: each robot's exit
line in its log ("robot 3, run ...: N ticks, ... B bad messages, S stale") and the world's metrics
(stale_messages; bad_messages minus the robots' own counts, which the world adds from their
statuses). Prints the table and exits 0 when every check holds, 1 otherwise.

What cannot be read exactly from outside (said in the output): duplicates (the robots' exit line and
the world's metrics do not report BadMessages.duplicates; this bench sends none, so bad + stale is
exact) and the run followers' counters (robots and the leader count bad world/run messages in a
separate counter they do not report). The leader's counters are read from its run line in its log
(world/clock after the start barrier reaches the leader only), the launcher's from the metrics
(`launcher_bad_messages`).
"""

from __future__ import annotations

import argparse
import collections
import json
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import psutil

from swarm.core import scenario_file
from swarm.core.scenario_file import Overrides
from swarm.core.sim import Simulation
from swarm.proto import keys, protocol
from swarm.proto.protocol import Clock, Cmd, Pose, Ref, State, Status

FLEET = "hostile"
START_TICK = 100  # the attack starts once the world is past this tick: t >= 2 s at dt = 0.02 s, so every
#                   message below with t <= 1 s or seq <= 7 is older than what the receivers have
CELL_STABLE_S = 0.3  # wall s: a robot's recent cells, for the certainty of a cell's subscribers
CELL_MARGIN_M = 0.25  # m: how far inside (or outside) a cell's reach a robot must be to count as certain: the
#                       bench's view of the poses may lag the robots' by a few ticks (0.01-0.02 m each here)
BIG_EVERY_S = 1.0  # wall s between two rounds of oversized payloads
BIG_SEQ = 2**53 - 1

# verdicts a receiver must give (see the module docstring)
BAD, STALE, IGNORED, ZENOH, UNCOUNTED = "bad", "stale", "ignored", "zenoh", "uncounted"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def pack(d: dict) -> bytes:
    return msgpack.packb(d, use_bin_type=True)


MALFORMED = [
    ("unhashable kind", pack({"v": 1, "kind": [1]})),
    ("empty", b""),
    ("garbage bytes", b"\xc1\xff"),
    ("kind is a map", pack({"v": 1, "kind": {"x": 1}})),
    ("version 2", pack({"v": 2, "kind": "pose", "t": 5.0, "seq": 300, "x": 0.0, "y": 0.0, "theta": 0.0})),
]


class Ledger:
    """What was sent, per key class and attack, and what each receiver must count."""

    def __init__(self) -> None:
        self.sent = collections.Counter()  # (key class, attack) -> messages
        self.expect = collections.defaultdict(collections.Counter)  # receiver -> verdict -> messages
        self.total = 0
        self.bytes = 0

    def add(self, klass: str, attack: str, payload: bytes, verdicts: list[tuple[str, str]]) -> None:
        self.sent[(klass, attack)] += 1
        self.total += 1
        self.bytes += len(payload)
        for receiver, verdict in verdicts:
            self.expect[receiver][verdict] += 1


class Cells:
    """Every robot's cell, from the poses the world publishes (the bench's own subscription)."""

    def __init__(self, n: int, side: float) -> None:
        self.n, self.side = n, side
        self.lock = threading.Lock()
        self.history: list[collections.deque] = [collections.deque() for _ in range(n)]  # (wall s, cell)
        self.seq = [-1] * n
        self.xy = [(0.0, 0.0)] * n

    def on_pose(self, key: str, payload: bytes) -> None:
        parsed = keys.parse(key)
        if parsed is None or parsed.kind != "pose" or parsed.id is None or parsed.id >= self.n:
            return
        try:
            p = protocol.decode(payload, "pose")
        except protocol.ProtocolError:
            return
        i, cell, now = parsed.id, keys.cell_of(p.x, p.y, self.side), time.monotonic()
        with self.lock:
            if p.seq <= self.seq[i]:
                return
            self.seq[i] = p.seq
            self.xy[i] = (p.x, p.y)
            h = self.history[i]
            if not h or h[-1][1] != cell:
                h.append((now, cell))

    def ready(self) -> bool:
        with self.lock:
            return all(self.history)

    def current(self, i: int) -> tuple[int, int]:
        with self.lock:
            return self.history[i][-1][1]

    def _inside(self, x: float, y: float, cell: tuple[int, int], reach: int) -> float:
        """How far (x, y) is inside the square of the cells within `reach` cells of `cell` [m] (< 0: outside)."""
        s = self.side
        x0, x1 = (cell[0] - reach) * s, (cell[0] + reach + 1) * s
        y0, y1 = (cell[1] - reach) * s, (cell[1] + reach + 1) * s
        return min(x - x0, x1 - x, y - y0, y1 - y)

    def subscribers(self, cell: tuple[int, int]) -> list[int] | None:
        """The robots subscribed to `cell` now, or None when some robot's membership is not certain: its
        cells of the last CELL_STABLE_S must all be within one cell of `cell` (subscribed: the block
        around each) or all three or more away (not: the block it left is kept for one tick only), and
        its position must be CELL_MARGIN_M inside that block's square, or as far outside the 5 x 5
        cells around `cell` (the bench's view of the poses may lag a few ticks behind the robots')."""
        now = time.monotonic()
        out = []
        with self.lock:
            for i, h in enumerate(self.history):
                while len(h) > 1 and h[1][0] < now - CELL_STABLE_S:
                    h.popleft()  # h[0] is the cell held at now - CELL_STABLE_S; later ones since
                d = [max(abs(c[0] - cell[0]), abs(c[1] - cell[1])) for _, c in h]
                x, y = self.xy[i]
                if all(k <= 1 for k in d) and self._inside(x, y, cell, 1) >= CELL_MARGIN_M:
                    out.append(i)
                elif not (all(k >= 3 for k in d) and self._inside(x, y, cell, 2) <= -CELL_MARGIN_M):
                    return None
        return out


class Attack:
    """The attack messages, each with what every receiver must make of it."""

    def __init__(self, n: int, cells: Cells, ledger: Ledger, dt: float) -> None:
        self.n, self.cells, self.ledger, self.dt = n, cells, ledger, dt  # dt: lock-step's tick (t = seq x dt)
        self.robots = [f"robot {i}" for i in range(n)]
        self.stranger = n  # next id outside the scenario
        self.cell_turn = [0] * n  # which cell of robot i's neighbourhood is next

    def _all(self, verdict: str) -> list[tuple[str, str]]:
        return [(r, verdict) for r in self.robots]

    def static(self) -> list[tuple[str, str, str, bytes, list]]:
        """(key class, key, attack, payload, verdicts) of every key but the cells."""
        F, n, out = FLEET, self.n, []

        def malformed(klass: str, key: str, verdicts: list) -> None:
            for name, payload in MALFORMED:
                out.append((klass, key, name, payload, verdicts))

        ref = keys.leader_ref(F)
        malformed("leader/ref", ref, self._all(BAD))
        out += [("leader/ref", ref, "t 7 dt, seq 7 (stale)", protocol.encode(
                    Ref(t=7 * self.dt, seq=7, x=60.0, y=0.0, theta=0.0, v=0.5, w=0.0)), self._all(STALE)),
                ("leader/ref", ref, "t 1e9, seq 7 (forged: t not seq x dt)", protocol.encode(
                    Ref(t=1e9, seq=7, x=60.0, y=0.0, theta=0.0, v=0.5, w=0.0)), self._all(BAD)),
                ("leader/ref", ref, "t 1, seq 2^53-1 (forged)", protocol.encode(
                    Ref(t=1.0, seq=BIG_SEQ, x=60.0, y=0.0, theta=0.0, v=0.5, w=0.0)), self._all(BAD)),
                ("leader/ref", ref, "t 1e8, seq 2^53-1 (jump)", protocol.encode(
                    Ref(t=1e8, seq=BIG_SEQ, x=60.0, y=0.0, theta=0.0, v=0.5, w=0.0)), self._all(BAD)),
                ("leader/ref", ref, "vel 1.7e308", pack({"v": 1, "kind": "ref", "t": 5.0, "seq": 300, "x": 0.0,
                                                         "y": 0.0, "theta": 0.0, "vel": 1.7e308, "w": 0.0}),
                 self._all(BAD))]
        for i in range(n):
            me = [(f"robot {i}", BAD)]
            pose = keys.robot_pose(F, i)
            malformed("robot/<id>/pose", pose, me)
            out += [("robot/<id>/pose", pose, "t 1, seq 2^53-1 (forged)", protocol.encode(
                        Pose(t=1.0, seq=BIG_SEQ, x=0.0, y=0.0, theta=0.0)), me),
                    ("robot/<id>/pose", pose, "t 1e8, seq 2^53-1 (jump)", protocol.encode(
                        Pose(t=1e8, seq=BIG_SEQ, x=0.0, y=0.0, theta=0.0)), me),
                    ("robot/<id>/pose", pose, "t 0, seq 0 (stale)", protocol.encode(
                        Pose(t=0.0, seq=0, x=0.0, y=0.0, theta=0.0)), [(f"robot {i}", STALE)]),
                    ("robot/<id>/pose", pose, "x 1e7 (beyond 1e6 m)", protocol.encode(
                        Pose(t=5.0, seq=300, x=1e7, y=0.0, theta=0.0)), me)]
            cmd = keys.robot_cmd(F, i)
            malformed("robot/<id>/cmd", cmd, [("world", BAD)])
            out += [("robot/<id>/cmd", cmd, "vel 1.7e308", pack({"v": 1, "kind": "cmd", "t": 1.0, "seq": 3,
                                                                 "vel": 1.7e308, "w": 0.0}), [("world", BAD)]),
                    ("robot/<id>/cmd", cmd, "seq 2^53-1 (a later tick)", protocol.encode(
                        Cmd(t=1.0, seq=BIG_SEQ, v=0.1, w=0.0)), [("world", BAD)]),
                    ("robot/<id>/cmd", cmd, "t 0, seq 0 (stale)", protocol.encode(Cmd(t=0.0, seq=0, v=0.1, w=0.0)),
                     [("world", STALE)])]
            status = keys.robot_status(F, i)
            malformed("robot/<id>/status", status, [("world", BAD)])
            out += [("robot/<id>/status", status, "t 1e8 (jump)", protocol.encode(Status(
                        t=1e8, ex=0.0, ey=0.0, etheta=0.0, frozen=False, neighbours=0, stale=0, bad=10**6)),
                     [("world", BAD)]),
                    ("robot/<id>/status", status, "t 0 (stale)", protocol.encode(Status(
                        t=0.0, ex=0.0, ey=0.0, etheta=0.0, frozen=False, neighbours=0, stale=0, bad=10**6)),
                     [("world", STALE)])]
        clock = keys.world_clock(F)  # after the start barrier only the leader listens (robots drop it)
        malformed("world/clock", clock, [("leader", BAD)])
        out += [("world/clock", clock, "t 1, seq 10^9 (forged)", protocol.encode(
                    Clock(t=1.0, seq=10**9, epoch=0.0, speed=1.0)), [("leader", BAD)]),
                ("world/clock", clock, "t dt, seq 1 (stale)", protocol.encode(
                    Clock(t=self.dt, seq=1, epoch=0.0, speed=1.0)), [("leader", STALE)]),
                ("world/clock", clock, "t 1e8, seq 10^9 (jump)", protocol.encode(
                    Clock(t=1e8, seq=10**9, epoch=0.0, speed=1.0)), [("leader", BAD)])]
        malformed("world/progress", keys.world_progress(F), [("nobody (--no-viz)", UNCOUNTED)])  # swarm up: a pipe
        malformed("world/run", keys.world_run(F), [("run followers", UNCOUNTED)])
        malformed("world/snapshot", keys.world_snapshot(F), [("nobody (--no-viz)", UNCOUNTED)])
        malformed("estop", keys.estop(F), self._all(BAD))
        return out

    def oversized(self) -> list[tuple[str, str, str, bytes, list]]:
        """Payloads beyond zenoh's size filter (64 KiB on small keys, 16 MiB on the large ones)."""
        F = FLEET
        cx, cy = self.cells.current(0)
        return [("leader/ref", keys.leader_ref(F), "100 kB", b"\x00" * 100_000, [("zenoh size filter", ZENOH)]),
                ("cell/<cx>/<cy>/<id>", keys.cell(F, cx, cy, 0), "10 MB", b"\x00" * (10 << 20),
                 [("zenoh size filter", ZENOH)]),
                ("world/snapshot", keys.world_snapshot(F), "20 MB", b"\x00" * (20 << 20),
                 [("zenoh size filter", ZENOH)])]

    def cell_round(self) -> list:
        """Markers, one per robot: each expands, when its turn comes (`cells_of`), into the attacks on one
        cell of that robot's neighbourhood."""
        return [("cells", i) for i in range(self.n)]

    def cells_of(self, i: int) -> list[tuple[str, str, str, bytes, object]]:
        """Attacks on the next cell of robot i's neighbourhood (its 9 cells in turn) whose subscribers are
        certain now ([] if none is). Their verdicts are decided again as each is sent (`verdicts`)."""
        F, n, out = FLEET, self.n, []
        klass = "cell/<cx>/<cy>/<id>"
        cx0, cy0 = self.cells.current(i)
        for _ in range(9):
            k = self.cell_turn[i]
            self.cell_turn[i] = (k + 1) % 9
            c = (cx0 + k % 3 - 1, cy0 + k // 3 - 1)
            if self.cells.subscribers(c) is not None:
                break
        else:
            return out
        key = keys.cell(F, c[0], c[1], i)
        for name, payload in MALFORMED:
            out.append((klass, key, name, payload, (c, None)))
        x, y = (c[0] + 0.5) * self.cells.side, (c[1] + 0.5) * self.cells.side
        ahead = protocol.encode(State(id=i, t=1e8, seq=BIG_SEQ, x=x, y=y, theta=0.0, r=0.3, R=1.2, frozen=False))
        out.append((klass, key, "own id, seq 2^53-1 (ahead)", ahead, (c, i)))
        other = protocol.encode(State(id=(i + 1) % n, t=5.0, seq=300, x=x, y=y, theta=0.0, r=0.3, R=1.2,
                                      frozen=False))
        out.append((klass, key, "payload id != key id", other, (c, None)))
        s = self.stranger
        self.stranger = n + (s - n + 1) % 2000
        stranger = protocol.encode(State(id=s, t=5.0, seq=300, x=x, y=y, theta=0.0, r=0.3, R=1.2, frozen=False))
        out.append((klass, keys.cell(F, c[0], c[1], s), "id outside the scenario", stranger, (c, None)))
        noid = keys.cell_any(F, c[0], c[1])[:-1] + "x"  # a cell key whose last chunk is no id
        out.append((klass, noid, "key without an id", other, (c, None)))
        return out

    def verdicts(self, spec) -> list[tuple[str, str]] | None:
        """What each receiver must make of a message now: a list as given, or for a cell attack (cell,
        owner) the cell's subscribers now (bad, the owner too: a state with its own id is an impostor); None when some robot's
        membership of the cell is not certain (the message is then not sent)."""
        if isinstance(spec, list):
            return spec
        c, owner = spec
        subs = self.cells.subscribers(c)
        if subs is None:
            return None
        return [(f"robot {j}", BAD) for j in subs] or [("no subscriber", UNCOUNTED)]


def run_attack(session, attack: Attack, ledger: Ledger, rate: float, seconds: float) -> float:
    """Send at `rate` messages a second for `seconds`; returns the wall time it took."""
    import zenoh

    put = session.put
    block, remote = zenoh.CongestionControl.BLOCK, zenoh.Locality.REMOTE
    static = attack.static()
    t0 = time.monotonic()
    end = t0 + seconds
    next_big = t0
    queue: list = []
    sent = 0
    while True:
        now = time.monotonic()
        if now >= end:
            break
        if now >= next_big:
            next_big += BIG_EVERY_S
            queue = attack.oversized() + queue
        due = int((now - t0) * rate) + 1 - sent
        if due <= 0:
            time.sleep(min(0.005, end - now))
            continue
        for _ in range(min(due, 200)):
            if not queue:
                queue = [x for pair in zip(attack.cell_round(), [static[j::attack.n] for j in range(attack.n)])
                         for x in (pair[0], *pair[1])]  # a robot's cell, then a share of the other keys
            item = queue.pop(0)
            if item[0] == "cells":
                queue[:0] = attack.cells_of(item[1])  # sent now, while the cell's subscribers are as judged
                continue
            klass, key, name, payload, spec = item
            verdicts = attack.verdicts(spec)
            if verdicts is None:
                continue  # a cell whose subscribers are not certain now: not sent
            put(key, payload, congestion_control=block, allowed_destination=remote)
            ledger.add(klass, name, payload, verdicts)
            sent += 1
    return time.monotonic() - t0


ROBOT_LINE = re.compile(r"robot (\d+), run (\S+): (\d+) ticks, (\d+) skipped, (\d+) states and \d+ references "
                        r"received, (\d+) bad messages, (\d+) stale")


LEADER_LINE = re.compile(r"leader: run (\S+) (?:ended|stopped): (\d+) references sent; clock messages refused (\d+), "
                         r"stale (\d+)")


def leader_counts(log_dir: Path) -> tuple[int, int] | None:
    """(bad, stale) of the leader's last run line in its log, None if it wrote none."""
    path = log_dir / "leader.log"
    found = list(LEADER_LINE.finditer(path.read_text(errors="replace"))) if path.exists() else []
    return (int(found[-1].group(3)), int(found[-1].group(4))) if found else None


def robot_counts(log_dir: Path, n: int) -> dict[int, tuple[int, int]]:
    out = {}
    for i in range(n):
        path = log_dir / f"robot-{i}.log"
        text = path.read_text(errors="replace") if path.exists() else ""
        found = [m for m in ROBOT_LINE.finditer(text) if int(m.group(1)) == i]
        if found:
            m = found[-1]
            out[i] = (int(m.group(6)), int(m.group(7)))
    return out


def kill_tree(proc: subprocess.Popen, known: list[psutil.Process]) -> None:
    """Kill, by PID, `swarm up` and every process it started that is still there."""
    procs = list(known)
    try:
        procs += psutil.Process(proc.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        pass
    for p in procs:
        try:
            p.kill()
        except psutil.NoSuchProcess:
            pass
    if proc.poll() is None:
        proc.kill()
        proc.wait(10)


FLOOD_PUTS = 20_000
BIG_PUTS, BIG_MIB = 12, 64
SETTLE_S = 2.0  # wall s after a flood that still counts as its cost


def _cpu(procs: list[psutil.Process]) -> float:
    total = 0.0
    for p in procs:
        try:
            c = p.cpu_times()
            total += c.user + c.system
        except psutil.Error:
            pass
    return total


def _rss_mib(p: psutil.Process | None) -> float:
    try:
        return p.memory_info().rss / 2**20 if p is not None else float("nan")
    except psutil.Error:
        return float("nan")


def floods(session, n: int, cells: Cells, progress: dict, robots: list[psutil.Process],
           router: psutil.Process | None) -> list[tuple[str, int, float, int, float, str]]:
    """Each flood in turn: (name, puts, wall s, missed commands, extra robot CPU [core s a robot], note)."""
    import zenoh

    block = zenoh.CongestionControl.BLOCK
    state = protocol.encode(State(id=3 % n, t=1.0, seq=1, x=0.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False))

    def one_id():
        key = f"swarm/{FLEET}/cell/*/*/{3 % n}"
        for _ in range(FLOOD_PUTS):
            session.put(key, state, congestion_control=block)
        return ""

    def many_ids():
        for j in range(FLOOD_PUTS):
            session.put(f"swarm/{FLEET}/cell/*/*/{10_000 + j}", state, congestion_control=block)
        return ""

    def forged_times():
        sent = 0
        while sent < FLOOD_PUTS:
            k = progress["seq"]
            for i in range(n):
                cx, cy = cells.current(i)
                for j in range(n):
                    if j != i:
                        session.put(keys.cell(FLEET, cx, cy, j), protocol.encode(State(
                            id=j, t=1e8, seq=k + 1, x=0.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False)),
                            congestion_control=block)
                        sent += 1
        return ""

    def oversized():
        before = _rss_mib(router)
        big = b"\x00" * (BIG_MIB << 20)
        for _ in range(BIG_PUTS):
            session.put(keys.robot_cmd(FLEET, 3 % n), big, congestion_control=block)
        session.put(keys.robot_cmd(FLEET, 3 % n), b"\xc1", congestion_control=block)  # after the big ones
        time.sleep(SETTLE_S)
        return f"router RSS {before:.0f} -> {_rss_mib(router):.0f} MiB"

    out = []
    for name, fn, puts in (("wildcard cell key, one id", one_id, FLOOD_PUTS),
                           ("wildcard cell keys, 20 000 ids", many_ids, FLOOD_PUTS),
                           ("forged-time states (seq k + 1, t = 1e8)", forged_times, FLOOD_PUTS),
                           (f"{BIG_PUTS} x {BIG_MIB} MiB on a command key", oversized, BIG_PUTS)):
        quiet0, m0 = _cpu(robots), progress["misses"]
        t0 = time.monotonic()
        time.sleep(SETTLE_S + 1.0)
        quiet = (_cpu(robots) - quiet0) / (time.monotonic() - t0)  # the robots' CPU a wall second, quiet
        c0, m0, t0 = _cpu(robots), progress["misses"], time.monotonic()
        note = fn()
        spent = time.monotonic() - t0
        time.sleep(SETTLE_S)
        wall = time.monotonic() - t0
        extra = (_cpu(robots) - c0 - quiet * wall) / max(1, len(robots))
        out.append((name, puts, spent, progress["misses"] - m0, extra, note))
        print(f"  {name:44} {puts:6d} puts in {spent:5.2f} s: missed commands {progress['misses'] - m0}, "
              f"extra robot CPU {extra:+.2f} core s a robot {note}", flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=7)
    ap.add_argument("--duration", type=float, default=200.0, help="simulated s (long enough to outlast the attack)")
    ap.add_argument("--rate", type=float, default=2000.0, help="attack messages a second")
    ap.add_argument("--attack-s", type=float, default=20.0, help="wall seconds of attack")
    ap.add_argument("--out", type=Path, help="where the run's files go (default: a new temp dir)")
    ap.add_argument("--floods", action="store_true", help="the floods, one after the other, each with its cost")
    a = ap.parse_args()
    out = a.out or Path(tempfile.mkdtemp(prefix="swarm-hostile-"))
    out.mkdir(parents=True, exist_ok=True)
    trace, metrics_path, log_dir = out / "t.npz", out / "m.json", out / "logs"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    scn = scenario_file.load("paper-50hz", Overrides(robots=a.robots, duration=a.duration),
                             progress=scenario_file.silent)
    cmd = [sys.executable, "-m", "swarm.cli", "up", "--robots", str(a.robots), "--duration", str(a.duration),
           "--no-viz", "--trace", str(trace), "--metrics", str(metrics_path), "--log-dir", str(log_dir),
           "--listen", endpoint, "--fleet", FLEET, "--quiet", "--start-timeout", "60"]
    print(f"swarm up: {a.robots} robots, {a.duration:g} s of paper-50hz, lock-step, fleet {FLEET} at {endpoint} "
          f"(files in {out})", flush=True)
    with open(out / "up.out", "w") as stdout, open(out / "up.err", "w") as stderr:
        proc = subprocess.Popen(cmd, stdout=stdout, stderr=stderr)  # the child holds its own copies
    children: list[psutil.Process] = []
    ledger = Ledger()
    progress = {"seq": -1, "t": 0.0}
    sys.setswitchinterval(0.0005)  # the pose callbacks must not wait long for the sending thread's GIL
    bus = None
    try:
        from swarm.net.bus import ZenohBus, zenoh_config

        deadline = time.monotonic() + 90
        while bus is None:  # the router may not listen yet
            try:
                conf = zenoh_config(connect=[endpoint])
                conf.insert_json5("low_pass_filter", "[]")  # a hostile client does not filter its own traffic
                # and waits as long as it takes to send a 64 MiB payload (ours closes a link stalled for 1 s)
                conf.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close", "60000000")
                bus = ZenohBus(conf)
            except Exception:  # noqa: BLE001 (zenoh raises its own error types while the router is not up)
                if time.monotonic() > deadline or proc.poll() is not None:
                    print("the router never came up")
                    return 1
                time.sleep(0.2)
        cells = Cells(scn.n, scn.cell_side)

        def on_progress(key: str, payload: bytes) -> None:
            try:
                p = protocol.decode(payload, "progress")
            except protocol.ProtocolError:
                return
            progress["seq"], progress["t"] = max(progress["seq"], p.seq), p.t
            progress["misses"] = max(progress.get("misses", 0), p.misses)

        bus.subscribe(keys.world_progress(FLEET), on_progress)
        bus.subscribe(keys.robot_any(FLEET, "pose"), cells.on_pose)
        while progress["seq"] < START_TICK or not cells.ready():
            if proc.poll() is not None:
                print(f"swarm up ended before the attack (exit {proc.returncode}); see {log_dir}")
                return 1
            if time.monotonic() > deadline:
                print(f"no progress past tick {START_TICK} in time; see {log_dir}")
                return 1
            time.sleep(0.05)
        children = psutil.Process(proc.pid).children(recursive=True)
        k0 = progress["seq"]
        if a.floods:
            return _floods_run(a, bus, proc, scn, cells, progress, children, trace, metrics_path, log_dir)
        print(f"attack: tick {k0} reached; {a.rate:g} messages a second for {a.attack_s:g} s ...", flush=True)
        spent = run_attack(bus.session, Attack(scn.n, cells, ledger, scn.dt), ledger, a.rate, a.attack_s)
        k1 = progress["seq"]
        print(f"attack: {ledger.total} messages ({ledger.bytes / 1e6:.1f} MB) in {spent:.1f} s "
              f"({ledger.total / spent:.0f} a second), ticks {k0}..{k1} ({(k1 - k0) / spent:.0f} ticks/s "
              "under attack)", flush=True)
        bus.close()
        bus = None
        try:
            rc = proc.wait(timeout=120 + 10 * a.duration)
        except subprocess.TimeoutExpired:
            print("swarm up did not end in time")
            return 1
    finally:
        if bus is not None:
            bus.close()
        kill_tree(proc, children)

    m = json.loads(metrics_path.read_text()) if metrics_path.exists() else {}
    q = np.load(trace)["q"] if trace.exists() else np.zeros((0, scn.n, 3))
    sim = Simulation(scn, record_period=scn.dt).run()
    diff = float(np.abs(q - sim.recording.q).max()) if q.shape == sim.recording.q.shape else None
    robots = robot_counts(log_dir, scn.n)

    print("\nsent, by key and attack:")
    by_class = collections.Counter()
    for (klass, name), count in sorted(ledger.sent.items()):
        by_class[klass] += count
        print(f"  {klass:22} {name:32} {count:7d}")
    print("  " + ", ".join(f"{k} {v}" for k, v in sorted(by_class.items())))

    checks: list[tuple[str, bool]] = []
    print("\nper receiver: what it must count (from what was sent to the keys it listens to) against what it counted")
    print(f"  {'receiver':22} {'sent to it':>10} {'bad':>8} {'stale':>8} {'ignored':>8} | "
          f"{'counted bad':>11} {'stale':>8}  {'':4}")
    sum_robot_bad = 0
    for i in range(scn.n):
        e = ledger.expect[f"robot {i}"]
        got = robots.get(i)
        ok = got is not None and got == (e[BAD], e[STALE])
        sum_robot_bad += got[0] if got else 0
        shown = f"{got[0]:11d} {got[1]:8d}" if got else f"{'no exit line':>20}"
        print(f"  {'robot ' + str(i):22} {sum(e.values()):10d} {e[BAD]:8d} {e[STALE]:8d} {e[IGNORED]:8d} | "
              f"{shown}  {'ok' if ok else 'DIFF'}")
        checks.append((f"robot {i}'s counters equal what was sent to it", ok))
    e = ledger.expect["world"]
    world_bad = m.get("bad_messages", -1) - sum_robot_bad
    world_stale = m.get("stale_messages", -1)
    ok = (world_bad, world_stale) == (e[BAD], e[STALE])
    print(f"  {'world':22} {sum(e.values()):10d} {e[BAD]:8d} {e[STALE]:8d} {e[IGNORED]:8d} | "
          f"{world_bad:11d} {world_stale:8d}  {'ok' if ok else 'DIFF'}")
    checks.append(("the world's counters equal what was sent to it", ok))
    e = ledger.expect["leader"]
    got = leader_counts(log_dir)
    ok = got == (e[BAD], e[STALE])
    shown = f"{got[0]:11d} {got[1]:8d}" if got else f"{'no run line':>20}"
    print(f"  {'leader':22} {sum(e.values()):10d} {e[BAD]:8d} {e[STALE]:8d} {e[IGNORED]:8d} | {shown}  "
          f"{'ok' if ok else 'DIFF'}")
    checks.append(("the leader's counters equal what was sent to it", ok))
    e = ledger.expect["launcher"]
    got_l = m.get("launcher_bad_messages", -1)
    ok = got_l == e[BAD]
    print(f"  {'launcher':22} {sum(e.values()):10d} {e[BAD]:8d} {e[STALE]:8d} {e[IGNORED]:8d} | {got_l:11d} "
          f"{'':8}  {'ok' if ok else 'DIFF'}")
    checks.append(("the launcher's count equals what was sent to it", ok))
    for who in ("run followers", "nobody (--no-viz)", "no subscriber", "zenoh size filter"):
        e = ledger.expect[who]
        what = "dropped by zenoh's size filter: never delivered" if who == "zenoh size filter" else \
            "no counter it reports"
        print(f"  {who:22} {sum(e.values()):10d} {'':8} {'':8} {'':8} | {what}")
    print("  (the world's bad = its metrics' bad_messages minus the robots' own counts, which it adds from their "
          "statuses;\n   duplicates are reported by neither the robots' exit line nor the metrics: none was sent, "
          "so bad + stale is exact)")

    print("\nthe run:")
    print(f"  exit code {rc}, failure {m.get('failure')!r}, collisions {m.get('collisions')}, cmd_misses "
          f"{m.get('cmd_misses')}, lockstep_overruns {m.get('lockstep_overruns')}, robots_lost {m.get('robots_lost')}, "
          f"steps {m.get('steps')}, run_wall_s {m.get('run_wall_s', 0):.1f}")
    print(f"  bad_messages {m.get('bad_messages')}, stale_messages {m.get('stale_messages')}")
    print(f"  trace against swarm sim: {q.shape[0]} steps, largest difference {diff}")
    checks += [("swarm up exited 0", rc == 0), ("metrics failure is null", m.get("failure", "missing") is None),
               ("no collision", m.get("collisions") == 0), ("no missed command", m.get("cmd_misses") == 0),
               ("no lock-step overrun", m.get("lockstep_overruns") == 0),
               ("the run outlasted the attack", k1 < scn.steps),
               (f"the attack sent at least 90 % of {a.rate * a.attack_s:.0f}", ledger.total >= 0.9 * a.rate * a.attack_s),
               ("the trace equals swarm sim's (largest difference 0)", diff == 0.0)]
    print("\nchecks:")
    for name, ok in checks:
        print(f"  {'ok  ' if ok else 'FAIL'} {name}")
    return 0 if all(ok for _, ok in checks) else 1


def _floods_run(a, bus, proc, scn, cells, progress, children, trace, metrics_path, log_dir) -> int:
    """--floods: the floods on the running swarm, then the run's checks."""
    def role(p: psutil.Process) -> str:
        try:
            cmd = p.cmdline()
        except psutil.Error:
            return ""
        return next((c for c in cmd if c in ("robot", "router", "world", "leader")), "")

    robots = [p for p in children if role(p) == "robot"]
    router = next((p for p in children if role(p) == "router"), None)
    progress.setdefault("misses", 0)
    print(f"floods on {len(robots)} robot processes, from tick {progress['seq']}:", flush=True)
    out = floods(bus.session, scn.n, cells, progress, robots, router)
    k1 = progress["seq"]
    try:
        rc = proc.wait(timeout=120 + 10 * a.duration)
    except subprocess.TimeoutExpired:
        print("swarm up did not end in time")
        return 1
    m = json.loads(metrics_path.read_text()) if metrics_path.exists() else {}
    q = np.load(trace)["q"] if trace.exists() else np.zeros((0, scn.n, 3))
    sim = Simulation(scn, record_period=scn.dt).run()
    diff = float(np.abs(q - sim.recording.q).max()) if q.shape == sim.recording.q.shape else None
    print("\n| flood | puts | sent in | missed commands | extra robot CPU (core s a robot) | note |")
    print("|---|---|---|---|---|---|")
    for name, puts, spent, missed, extra, note in out:
        print(f"| {name} | {puts} | {spent:.2f} s | {missed} | {extra:+.2f} | {note} |")
    print(f"\nthe run: exit {rc}, failure {m.get('failure')!r}, collisions {m.get('collisions')}, cmd_misses "
          f"{m.get('cmd_misses')}, bad_messages {m.get('bad_messages')}, trace against swarm sim: largest "
          f"difference {diff}")
    checks = [("swarm up exited 0", rc == 0), ("no collision", m.get("collisions") == 0),
              ("no missed command", m.get("cmd_misses") == 0), ("the run outlasted the floods", k1 < scn.steps),
              ("the trace equals swarm sim's (largest difference 0)", diff == 0.0)]
    for name, ok in checks:
        print(f"  {'ok  ' if ok else 'FAIL'} {name}")
    return 0 if all(ok for _, ok in checks) else 1


if __name__ == "__main__":
    sys.exit(main())

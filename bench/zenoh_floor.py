"""The floor under `swarm up`: the same processes and messages, with robots that compute nothing.

    python bench/zenoh_floor.py [--robots 37] [--duration 20] [--mode realtime|lockstep] [--rate 50]
                                [--work-us 0] [--transport tcp|unix] [--layout formation|start] [--wait]
                                [--callbacks]

It starts what `swarm up` starts (a router, a world, N robot processes, each a zenoh client of the
router with swarm's session settings and runtime, leaving the ingress checks to the router as `swarm up`'s
processes do: --router-checks) and moves the same messages. Real time: the world
sends robot i its pose at phase i/N of every control period; robot i blocks on its pose inbox, drains
the states in the 3x3 cells around its slot in the built-in scenario's formation (or its start
position: `--layout start`), sends its state on its own cell key and a command that echoes the pose's
time; the world drains its command inbox and takes the round trip. Lock-step: the world sends every
pose of a tick at once and waits for every command before the next tick (its robots wait for no
neighbour, so this bounds swarm's rate from above). `--wait` adds swarm's wait rule to lock-step: a
robot sends its state on its pose, then takes its command only once the state of that tick of every
robot in its 3x3 cells is in (it blocks on a cell's inbox that still lacks one): the floor of swarm's
two-phase tick, which no code in a robot can beat (docs/performance.md). `--callbacks` (with `--wait`) takes
the pose and the cells' states in Python callbacks on zenoh's threads that wake the loop (a condition
variable), as a swarm robot's lock-step does, instead of blocking in zenoh on inboxes:
the cost of that hand-over alone. Robots do nothing else, or spin `--work-us` of CPU
a period to stand in for decoding, the law and encoding. So the figures are what zenoh and 40 processes
cost on this machine: the floor under `python bench/up_speed.py` (docs/performance.md compares them).

Prints the round trip (median, p99, max) or the ticks per second, the states a robot took per period,
its loop thread's CPU per period, and the CPU of each role in cores, from /proc over the run.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarm.net.bus import ZENOH_RUNTIME, ZenohBus, _ZenohInbox, drainer, zenoh_config  # noqa: E402

PREFIX = "floor"
POSE = struct.Struct("<dI")  # time sent (CLOCK_MONOTONIC, shared by the machine's processes), robot id
PAD = bytes(80)  # a state or a pose of swarm is ~80-100 bytes of msgpack


def cells_of(n: int, layout: str) -> list[tuple[int, int]]:
    """The cell of every robot of the built-in scenario with n robots: at the start (spread out) or
    in formation (its slots around the leader's start: the densest, ~6 neighbours each)."""
    from swarm.proto import keys
    from swarm.core.scenario_file import Overrides, load

    sc = load("paper-50hz", Overrides(robots=n))
    if layout == "start":
        points = sc.poses[:, :2]
    else:
        x, y, _, _, _ = sc.leader.state(0.0)
        points = sc.offsets + (x, y)
    return [keys.cell_of(float(x), float(y), sc.cell_side) for x, y in points]


def neighbourhood(i: int, n: int, layout: str) -> tuple[list, tuple[int, int], list[tuple[int, int]]]:
    """Robot i's view of the layout: every robot's cell, its own, and the 3x3 block around it."""
    cells = cells_of(n, layout)
    cx, cy = cells[i]
    return cells, (cx, cy), [(cx + a, cy + b) for a in (-1, 0, 1) for b in (-1, 0, 1)]


def hint_neighbours(bus, i: int, cells: list, near_cells: list) -> None:
    """The keys robot i will hear, hinted to zenoh as a swarm robot does (ZenohBus.hint)."""
    for j, c in enumerate(cells):
        if j != i and c in near_cells:
            bus.hint(f"{PREFIX}/cell/{c[0]}/{c[1]}/{j}")


def write_figures(i: int, states: int, periods: int, loop_cpu: float, p0: float) -> None:
    """Robot i's figures for the parent (FLOOR_OUT): states taken and CPU [us] a period (p0: process_time at start)."""
    Path(os.environ["FLOOR_OUT"], f"robot-{i}.json").write_text(json.dumps(
        {"states_per_period": states / max(1, periods), "loop_us": 1e6 * loop_cpu / max(1, periods),
         "process_us": 1e6 * (time.process_time() - p0) / max(1, periods)}))


def robot(i: int, n: int, endpoint: str, layout: str, wait: bool, callbacks: bool = False) -> None:
    if callbacks:
        return robot_callbacks(i, n, endpoint, layout)
    cells, (cx, cy), near_cells = neighbourhood(i, n, layout)
    others = [sum(1 for j in range(n) if j != i and cells[j] == c) for c in near_cells]  # robots in each cell
    with ZenohBus(zenoh_config("client", connect=[endpoint], ingress_checks=False)) as bus:
        pose = bus.inbox(f"{PREFIX}/robot/{i}/pose", depth=8)
        near = [bus.inbox(f"{PREFIX}/cell/{c[0]}/{c[1]}/*", depth=64) for c in near_cells]
        mine, cmd = f"{PREFIX}/cell/{cx}/{cy}/{i}", f"{PREFIX}/robot/{i}/cmd"
        hint_neighbours(bus, i, cells, near_cells)
        token = bus.token(f"{PREFIX}/alive/{i}")
        drain_near = drainer(near)
        work = float(os.environ.get("FLOOR_WORK_US", "0")) * 1e-6
        states = periods = 0
        loop_cpu = 0.0
        stop = False

        def on_term(*_):
            nonlocal stop
            stop = True
            pose.wake()
            for c in near_cells:  # a robot blocked on a cell (--wait) wakes too: a local wake-up sample there
                bus.session.put(f"{PREFIX}/cell/{c[0]}/{c[1]}/wake", b"", attachment=_ZenohInbox.WAKE,
                                allowed_destination=bus._z.Locality.SESSION_LOCAL)

        signal.signal(signal.SIGTERM, on_term)
        p0 = time.process_time()
        while not stop:
            got = pose.wait() + pose.drain()
            if not got:
                continue
            c0 = time.thread_time()
            body = got[-1][1]
            if wait:  # lock-step as swarm: the state first, then the states of this tick of every robot near
                bus.put(mine, body + PAD, loopback=False)
                stamp, have = body[:POSE.size], [0] * len(near)
                while not stop:
                    for c, box in enumerate(near):
                        for _key, data in box.drain():
                            if data[:POSE.size] == stamp:  # this tick's (the pose's bytes lead a state)
                                have[c] += 1
                                states += 1
                    short = [c for c in range(len(near)) if have[c] < others[c]]
                    if not short:
                        break
                    loop_cpu += time.thread_time() - c0
                    for _key, data in near[short[0]].wait():  # blocks in zenoh until that cell has something
                        if data[:POSE.size] == stamp:
                            have[short[0]] += 1
                            states += 1
                    c0 = time.thread_time()
            else:
                states += len(drain_near())  # its 9 cells in one call, as a swarm robot drains them
            periods += 1
            if work:
                end = time.thread_time() + work
                while time.thread_time() < end:
                    pass
            if not wait:
                bus.put(mine, body + PAD, loopback=False)
            bus.put(cmd, body, reliable=True)
            loop_cpu += time.thread_time() - c0
        write_figures(i, states, periods, loop_cpu, p0)
        token.close()
        for box in near + [pose]:
            box.close()


def robot_callbacks(i: int, n: int, endpoint: str, layout: str) -> None:
    """--wait --callbacks: robot() with its pose and its cells' states taken in Python callbacks."""
    cells, (cx, cy), near_cells = neighbourhood(i, n, layout)
    expect = sum(1 for j in range(n) if j != i and cells[j] in near_cells)
    cond = threading.Condition()
    poses: list[bytes] = []
    states: list[bytes] = []
    with ZenohBus(zenoh_config("client", connect=[endpoint], ingress_checks=False)) as bus:
        def on_pose(_key: str, data: bytes) -> None:
            with cond:
                poses.append(data)
                cond.notify()

        def on_state(_key: str, data: bytes) -> None:
            with cond:
                states.append(data)
                cond.notify()

        subs = [bus.subscribe(f"{PREFIX}/robot/{i}/pose", on_pose)]
        subs += [bus.subscribe(f"{PREFIX}/cell/{c[0]}/{c[1]}/*", on_state) for c in near_cells]
        mine, cmd = f"{PREFIX}/cell/{cx}/{cy}/{i}", f"{PREFIX}/robot/{i}/cmd"
        hint_neighbours(bus, i, cells, near_cells)
        token = bus.token(f"{PREFIX}/alive/{i}")
        taken = periods = 0
        loop_cpu = 0.0
        stop = threading.Event()

        def on_term(*_):
            stop.set()
            with cond:
                cond.notify()

        signal.signal(signal.SIGTERM, on_term)
        p0 = time.process_time()
        early: list[bytes] = []  # states of the next tick that came before its pose
        while not stop.is_set():
            with cond:
                cond.wait_for(lambda: poses or stop.is_set(), 0.2)
                if not poses:
                    continue
                body = poses[-1]
                poses.clear()
            c0 = time.thread_time()
            bus.put(mine, body + PAD, loopback=False)
            stamp, have = body[:POSE.size], 0
            pending, early = early, []
            while not stop.is_set():
                for data in pending:
                    if data[:POSE.size] == stamp:
                        have += 1
                        taken += 1
                    else:
                        early.append(data)
                if have >= expect:
                    break
                loop_cpu += time.thread_time() - c0
                with cond:
                    cond.wait_for(lambda: states or stop.is_set(), 0.2)
                    pending = states[:]
                    states.clear()
                c0 = time.thread_time()
            periods += 1
            bus.put(cmd, body, reliable=True)
            loop_cpu += time.thread_time() - c0
        write_figures(i, taken, periods, loop_cpu, p0)
        token.close()
        for h in subs:
            h.close()


def world(n: int, endpoint: str, duration: float, rate: float, lockstep: bool) -> None:
    period = 1.0 / rate
    with ZenohBus(zenoh_config("client", connect=[endpoint], ingress_checks=False)) as bus:
        cmds = bus.inbox(f"{PREFIX}/robot/*/cmd", depth=4 * n)
        for i in range(n):  # as swarm's world does (ZenohBus.hint)
            bus.hint(f"{PREFIX}/robot/{i}/cmd")
        alive: set[str] = set()
        bus.watch_alive(f"{PREFIX}/alive/*", lambda key, up: alive.add(key) if up else alive.discard(key))
        deadline = time.monotonic() + 60
        while len(alive) < n:
            if time.monotonic() > deadline:
                sys.exit(f"zenoh_floor: only {len(alive)} of {n} robots came up in 60 s")
            time.sleep(0.05)
        keys = [f"{PREFIX}/robot/{i}/pose" for i in range(n)]
        rtt: list[float] = []
        warm = 1.0  # s of wall time left out of the figures (subscriptions settling)
        t0 = time.monotonic() + 0.1
        print("START", flush=True)
        if lockstep:
            return world_lockstep(bus, cmds, keys, t0 + warm, duration)
        k = 0
        while True:
            base = t0 + k * period
            if base - t0 > duration + warm:
                break
            for i in range(n):
                slot = base + period * i / n
                while (now := time.monotonic()) < slot:
                    for _, body in cmds.drain():
                        sent, _ = POSE.unpack_from(body)
                        if sent > t0 + warm:
                            rtt.append(now - sent)
                    time.sleep(min(0.0005, slot - now))
                bus.put(keys[i], POSE.pack(time.monotonic(), i))
            k += 1
        print("STOP", flush=True)
        rtt.sort()
        q = (lambda p: 1e3 * rtt[min(len(rtt) - 1, int(p * len(rtt)))]) if rtt else (lambda p: float("nan"))
        print(json.dumps({"commands": len(rtt), "expected": int(duration * rate) * n,
                          "median_ms": q(0.5), "p99_ms": q(0.99), "max_ms": q(1.0)}), flush=True)


def world_lockstep(bus, cmds, keys: list[str], t_start: float, duration: float) -> None:
    """Lock-step: every pose of tick k at once, then every command of tick k, then tick k + 1. The
    robots do not wait for their neighbours' states (swarm's do), so this bounds swarm's rate from above."""
    n, ticks, t_end = len(keys), 0, t_start + duration
    while (now := time.monotonic()) < t_end:
        stamp = POSE.pack(now, 0)
        for key in keys:
            bus.put(key, stamp, reliable=True)
        got = 0
        while got < n:
            got += len(cmds.wait()) + len(cmds.drain())
        ticks += now >= t_start
    print("STOP", flush=True)
    print(json.dumps({"ticks_per_s": ticks / duration}), flush=True)


def router(endpoint: str) -> None:
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with ZenohBus(zenoh_config("router", listen=[endpoint])):
        print("READY", flush=True)
        stop.wait(600)


def cpu_s(pid: int) -> float:
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=37)
    ap.add_argument("--duration", type=float, default=20.0, help="measured seconds (after 1 s of warm-up)")
    ap.add_argument("--rate", type=float, default=50.0, help="real time: control rate [Hz]")
    ap.add_argument("--mode", choices=("realtime", "lockstep"), default="realtime",
                    help="real time (the round trip at --rate) or lock-step (ticks per second, as fast as it goes)")
    ap.add_argument("--work-us", type=float, default=0.0, help="CPU a robot spins per period, standing in for the law")
    ap.add_argument("--transport", choices=("tcp", "unix"), default="tcp",
                    help="tcp on 127.0.0.1 (as swarm up), or a unix socket (unixsock-stream)")
    ap.add_argument("--layout", choices=("formation", "start"), default="formation",
                    help="robots' cells: their formation slots (dense) or their start poses (spread out)")
    ap.add_argument("--wait", action="store_true",
                    help="lock-step: each robot sends its state, then waits for this tick's state of every robot in "
                         "its 3x3 cells before its command (swarm's wait rule; without it the floor waits for no one)")
    ap.add_argument("--callbacks", action="store_true",
                    help="with --wait: the pose and the states in Python callbacks that wake the loop, not inboxes")
    ap.add_argument("--role", choices=("router", "world", "robot"), help=argparse.SUPPRESS)
    ap.add_argument("--id", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.robots < 1 or a.duration <= 0 or a.rate <= 0 or a.work_us < 0:
        ap.error("--robots, --duration and --rate must be positive, --work-us not negative")
    if a.wait and a.mode != "lockstep":
        ap.error("--wait is a lock-step rule: give --mode lockstep")
    if a.callbacks and not a.wait:
        ap.error("--callbacks goes with --wait")
    if a.role == "router":
        return router(a.endpoint)
    if a.role == "world":
        return world(a.robots, a.endpoint, a.duration, a.rate, a.mode == "lockstep")
    if a.role == "robot":
        return robot(a.id, a.robots, a.endpoint, a.layout, a.wait, a.callbacks)

    tmp = Path(tempfile.mkdtemp(prefix="floor-"))
    if a.transport == "tcp":
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    else:
        endpoint = f"unixsock-stream/{tmp / 'router.sock'}"
    env = dict(os.environ, FLOOR_WORK_US=str(a.work_us), FLOOR_OUT=str(tmp), PYTHONPATH=str(ROOT))
    me = [sys.executable, __file__, "--robots", str(a.robots), "--duration", str(a.duration), "--rate", str(a.rate),
          "--endpoint", endpoint, "--layout", a.layout, "--mode", a.mode] + (["--wait"] if a.wait else []) \
        + (["--callbacks"] if a.callbacks else [])
    procs: dict[str, list[subprocess.Popen]] = {"router": [], "world": [], "robot": []}

    def start(role: str, *extra: str, **kw) -> subprocess.Popen:
        e = dict(env, ZENOH_RUNTIME=ZENOH_RUNTIME) if role == "robot" else env  # as swarm's launcher does
        p = subprocess.Popen(me + ["--role", role, *extra], env=e, start_new_session=True, text=True, **kw)
        procs[role].append(p)
        return p

    def kill_all() -> None:
        for ps in (procs["robot"], procs["world"], procs["router"]):
            for p in ps:
                if p.poll() is None:
                    os.killpg(p.pid, signal.SIGKILL)
                    p.wait(timeout=10)

    watchdog = threading.Timer(a.duration + 120, kill_all)  # a hung run ends: the world's output then ends too
    watchdog.start()
    try:
        r = start("router", stdout=subprocess.PIPE)
        if r.stdout.readline().strip() != "READY":
            sys.exit("zenoh_floor: the router did not start")
        w = start("world", stdout=subprocess.PIPE)
        for i in range(a.robots):
            start("robot", "--id", str(i))
        if w.stdout.readline().strip() != "START":
            sys.exit("zenoh_floor: the world did not start")
        time.sleep(1.0)  # the world's warm-up second, left out of its figures too
        every = [p for ps in procs.values() for p in ps]
        c0, w0 = {p.pid: cpu_s(p.pid) for p in every}, time.monotonic()
        if w.stdout.readline().strip() != "STOP":
            sys.exit("zenoh_floor: the world failed")
        c1, w1 = {p.pid: cpu_s(p.pid) for p in every}, time.monotonic()
        res = json.loads(w.stdout.readline())
        w.wait(timeout=10)
        for p in procs["robot"]:
            p.send_signal(signal.SIGTERM)
        for p in procs["robot"]:
            p.wait(timeout=10)
        rows = [json.loads(f.read_text()) for f in tmp.glob("robot-*.json")]
        per = [r["states_per_period"] for r in rows]
        loop_us = sum(r["loop_us"] for r in rows) / max(1, len(rows))
        process_us = sum(r["process_us"] for r in rows) / max(1, len(rows))
        cores = {role: sum(c1[p.pid] - c0[p.pid] for p in ps) / (w1 - w0) for role, ps in procs.items()}
        if a.mode == "lockstep":
            head = f"N = {a.robots}, lock-step{' waiting for states' if a.wait else ''}{' in callbacks' if a.callbacks else ''}, {a.transport}, {a.layout}, " \
                   f"work {a.work_us:g} us/tick, {a.duration:g} s: " \
                   f"{res['ticks_per_s']:.1f} ticks/s; "
        else:
            head = f"N = {a.robots}, {a.rate:g} Hz, {a.transport}, {a.layout}, work {a.work_us:g} us/period, " \
                   f"{a.duration:g} s: round trip median {res['median_ms']:.2f} ms, p99 {res['p99_ms']:.2f} ms, max " \
                   f"{res['max_ms']:.1f} ms ({res['commands']} of {res['expected']} commands); "
        per_what = "tick" if a.mode == "lockstep" else "period"
        print(head +
              f"{sum(per) / max(1, len(per)):.1f} states per robot per {per_what}; a robot's loop thread {loop_us:.0f} us "
              f"of CPU per {per_what} (work included), the whole robot process {process_us:.0f} us; CPU [cores]: "
              + ", ".join(f"{k} {v:.2f}" for k, v in cores.items()) + f" (robot {100 * cores['robot'] / a.robots:.1f} % each)")
    finally:
        watchdog.cancel()
        kill_all()
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()

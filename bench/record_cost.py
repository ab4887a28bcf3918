"""What the live recorder (swarm.view.record.BusRecorder) costs per message.

    python bench/record_cost.py                 # N = 37 and 500, 400 frames each
    python bench/record_cost.py --robots 37 --frames 1000
    python bench/record_cost.py --up --robots 37 --duration 20 --repeats 3   # end to end, see bench_up

The traffic of one lock-step tick of `swarm up` (paper-50hz: dt = 0.02 s, statuses every 0.1 s)
is encoded with swarm.proto.protocol as the processes would send it: one world snapshot of N robots, one
leader reference, N commands and about N / 5 statuses. Each message goes through the recorder's bus
callback (the part on zenoh's receiving thread: an append to a deque) and then through its worker
(decode, events, decimation to record_hz, JSON, MCAP with zstd), timed one message at a time with
perf_counter. Robots drive unicycle arcs from the scenario's random start poses at random (v, w); a few are
frozen and 5 % of statuses flip the flag, so events are written too.

Budget: the recorder may cost a 37-robot `swarm up` at most 10 % of its wall time. The swarm keeps
both cores busy (about 41 ticks/s, README), so the recorder's CPU per tick over the 2 cores' CPU per
tick estimates the slowdown; `--up` measures it end to end (noisy on a shared VM: repeat it).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from swarm.proto import keys, protocol
from swarm.core import scenario_file
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto.protocol import Cmd, Ref, RobotSnap, Snapshot, Status
from swarm.view.record import BusRecorder, Recorder

FLEET = "bench"


def _stats(us: list[float]) -> dict:
    a = np.asarray(us)
    return {"median_us": float(np.median(a)), "p95_us": float(np.percentile(a, 95)), "mean_us": float(a.mean()),
            "count": int(a.size)}


def traffic(n_robots: int, frames: int, seed: int = 0):
    """The encoded messages of `frames` lock-step ticks: yields (topic, key, payload) in tick order."""
    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=n_robots, seed=seed))
    rng = np.random.default_rng(seed)
    q = np.array(scn.poses, float)
    table = scn.leader.table()
    dt = scn.dt
    from swarm.core import kinematics

    frozen = rng.random(n_robots) < 0.2
    for k in range(frames):
        t = k * dt
        v = np.clip(rng.normal(0.5, 0.2, n_robots), -1.0, 1.5)
        w = rng.normal(0.0, 0.3, n_robots)
        q[:, 0] += v * dt * np.cos(q[:, 2])
        q[:, 1] += v * dt * np.sin(q[:, 2])
        q[:, 2] += w * dt
        rows = tuple(RobotSnap(i, float(q[i, 0]), float(q[i, 1]), float(q[i, 2]), float(v[i]), float(w[i]),
                               False, True) for i in range(n_robots))
        yield "/world/snapshot", keys.world_snapshot(FLEET), protocol.encode(Snapshot(t, k, rows))
        x, y, th, vl, wl = kinematics.leader_state(table, t)
        yield "/leader/ref", keys.leader_ref(FLEET), protocol.encode(Ref(t, k, x, y, th, vl, wl))
        for i in range(n_robots):
            yield "/robot/cmd", keys.robot_cmd(FLEET, i), protocol.encode(Cmd(t, k, float(v[i]), float(w[i])))
        for i in range(k % 5, n_robots, 5):  # each robot every 5 ticks = 0.1 s, staggered
            if rng.random() < 0.05:
                frozen[i] = not frozen[i]
            yield "/robot/status", keys.robot_status(FLEET, i), protocol.encode(Status(
                t, float(rng.normal(0, 0.5)), float(rng.normal(0, 0.5)), float(rng.normal(0, 0.3)),
                bool(frozen[i]), 6, 0, 0))


def bench_recorder(n_robots: int, frames: int, record_hz: float = 20.0, seed: int = 0) -> dict:
    """Cost of recording `frames` ticks of an n_robots swarm: per snapshot frame, per command and per
    status message [microseconds, median / p95], per tick in all, and the file's size. Also prints it."""
    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=n_robots, seed=seed))
    msgs = list(traffic(n_robots, frames, seed))
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "bench.mcap")
        # the bus callback alone (what runs on zenoh's receiving thread): a throwaway recorder
        net = MemoryNet()
        side = BusRecorder(MemoryBus(net), FLEET, Recorder(os.path.join(tmp, "cb.mcap"), scn, record_hz),
                           threaded=False)
        sample = msgs[:5000]
        t0 = time.perf_counter()
        for topic, key, payload in sample:
            side.callbacks[topic](key, payload)
        cb_us = (time.perf_counter() - t0) / len(sample) * 1e6
        assert side.pending == len(sample)
        side.close(None)  # processes them (not timed)
        rec = Recorder(path, scn, record_hz, source="bench", fleet=FLEET)
        br = BusRecorder(MemoryBus(MemoryNet()), FLEET, rec, threaded=False)  # driven one message at a time
        per: dict[str, list[float]] = {"/world/snapshot": [], "/leader/ref": [], "/robot/cmd": [],
                                       "/robot/status": []}
        clock = time.perf_counter
        cpu0, wall0 = time.process_time(), clock()
        for topic, key, payload in msgs:
            t1 = clock()
            br.process(topic, key, payload)
            per[topic].append((clock() - t1) * 1e6)
        t1 = clock()
        br.close({"robots": n_robots})
        close_ms = (clock() - t1) * 1e3
        cpu = time.process_time() - cpu0
        wall = clock() - wall0
        size = os.path.getsize(path)
    out = {
        "robots": n_robots, "frames": frames, "record_hz": record_hz,
        "snapshot": _stats(per["/world/snapshot"]), "ref": _stats(per["/leader/ref"]),
        "cmd": _stats(per["/robot/cmd"]), "status": _stats(per["/robot/status"]),
        "callback_us": cb_us,
        "per_tick_ms": wall / frames * 1e3, "per_tick_cpu_ms": cpu / frames * 1e3, "close_ms": close_ms,
        "bytes_per_tick": size / frames, "events": rec.counts["/events"],
    }
    print(f"N = {n_robots:4d}, {frames} ticks, record_hz {record_hz:g}: "
          f"snapshot {out['snapshot']['median_us']:.0f} / {out['snapshot']['p95_us']:.0f} us (median / p95), "
          f"cmd {out['cmd']['median_us']:.1f} / {out['cmd']['p95_us']:.1f} us, "
          f"status {out['status']['median_us']:.1f} / {out['status']['p95_us']:.1f} us, "
          f"ref {out['ref']['median_us']:.1f} us, callback {cb_us:.2f} us; "
          f"per tick {out['per_tick_ms']:.3f} ms (CPU {out['per_tick_cpu_ms']:.3f} ms), "
          f"{out['bytes_per_tick'] / 1024:.1f} KiB/tick, close {close_ms:.0f} ms, {out['events']} events")
    return out


# --------------------------------------------------------------------------- end to end


def _cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def side_recorder(endpoint: str, fleet: str, robots: int, duration: float, path: str, metrics_path: str,
                  record_hz: float, null: bool = False) -> None:
    """A recorder process on a running `swarm up`: records until the world's liveliness token goes,
    closes with the world's metrics and prints its CPU seconds (JSON on stdout): in all, before the
    world came up (start-up) and during the run. null: the same subscriptions with callbacks that do
    nothing (what receiving alone costs)."""
    from swarm.net.bus import ZenohBus, zenoh_config

    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=robots, duration=duration))
    end = time.monotonic() + 30.0
    while True:
        try:
            bus = ZenohBus(zenoh_config("client", connect=[endpoint]))
            break
        except Exception:
            if time.monotonic() > end:
                raise
            time.sleep(0.1)
    world_seen, world_gone = threading.Event(), threading.Event()

    def alive(_key: str, up: bool) -> None:
        (world_seen if up else world_gone).set()

    rec = Recorder(path, scn, record_hz, source="lockstep", fleet=fleet)
    if null:
        received = [0]
        seen: list[bytes] = []

        def count(key: str, payload: bytes) -> None:
            received[0] += 1
            if key.endswith("/snapshot"):
                seen.append(payload)

        for k in (keys.world_snapshot(fleet), keys.leader_ref(fleet), keys.robot_any(fleet, "cmd"),
                  keys.robot_any(fleet, "status")):
            bus.subscribe(k, count)
    else:
        br = BusRecorder(bus, fleet, rec)
    bus.watch_alive(keys.alive(fleet, "world"), alive)
    world_seen.wait(120.0)
    cpu_start = _cpu()
    world_gone.wait(60.0 + 20.0 * duration)
    cpu_run = _cpu() - cpu_start
    for _ in range(50):  # the launcher rewrites the metrics after the world's exit
        if Path(metrics_path).is_file():
            break
        time.sleep(0.1)
    try:
        metrics = json.loads(Path(metrics_path).read_text())
    except (OSError, ValueError):
        metrics = None
    c0 = _cpu()
    if null:
        rec.close(metrics)
    else:
        br.close(metrics)
    cpu_close = _cpu() - c0
    bus.close()
    if null:
        seqs = sorted(protocol.decode(b, "snapshot").seq for b in seen)
        n_snap, first = len(seqs), (seqs[0] if seqs else None)
        missed = (seqs[-1] - seqs[0] + 1 - len(seqs)) if seqs else 0
    else:
        n_snap, first, missed = br.snapshots, br.first_seq, br.snapshots_missed
    print(json.dumps({"cpu_s": _cpu(), "cpu_startup_s": cpu_start, "cpu_run_s": cpu_run, "cpu_close_s": cpu_close,
                      "snapshots": n_snap, "first_seq": first, "missed": missed,
                      "received": received[0] if null else br.received, "bad": 0 if null else br.bad,
                      "written": rec.counts, "bytes": os.path.getsize(path)}))


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def bench_up(n_robots: int = 37, duration: float = 20.0, repeats: int = 3, record_hz: float = 20.0) -> dict:
    """`swarm up` (lock-step, paper-50hz, no viewer) with and without a recorder attached, alternating.

    The recorder runs in its own process (a zenoh client of the same router, the same subscriptions
    and work as an in-launcher BusRecorder). Compares the world's run time (run_wall_s, launch
    excluded) and reports the recorder's CPU per tick. Needs a working `swarm up` (swarm.cli)."""
    out = Path(tempfile.mkdtemp(prefix="swarm-record-bench-"))
    rows: dict[str, list[float]] = {"plain": [], "receive only": [], "recorded": []}
    cpu_per_tick: dict[str, list[float]] = {"receive only": [], "recorded": []}
    for rep in range(repeats):
        for mode in rows:
            port, fleet = _free_port(), f"recbench{rep}{mode[0]}"
            metrics = out / f"m-{rep}-{mode}.json"
            cmd = [sys.executable, "-m", "swarm.cli", "up", "--robots", str(n_robots), "--duration", str(duration),
                   "--listen", f"tcp/127.0.0.1:{port}", "--fleet", fleet, "--metrics", str(metrics),
                   "--log-dir", str(out / f"logs-{rep}-{mode}"), "--quiet", "--no-viz"]
            up = subprocess.Popen(cmd)
            side = None
            if mode != "plain":
                side = subprocess.Popen([sys.executable, __file__, "--side-recorder", f"tcp/127.0.0.1:{port}", fleet,
                                         str(n_robots), str(duration), str(out / f"r-{rep}.mcap"), str(metrics),
                                         str(record_hz), "null" if mode == "receive only" else "full"],
                                        stdout=subprocess.PIPE, text=True)
            up.wait(timeout=120 + 20 * duration)
            m = json.loads(metrics.read_text())
            rows[mode].append(m["run_wall_s"])
            line = f"  {mode:>12}: run {m['run_wall_s']:.2f} s, {m['steps'] / m['run_wall_s']:.1f} ticks/s"
            if side is not None:
                so, _ = side.communicate(timeout=60)
                r = json.loads(so.strip().splitlines()[-1])
                cpu_per_tick[mode].append(r["cpu_run_s"] / m["steps"] * 1e3)
                line += (f"; side process CPU: start-up {r['cpu_startup_s']:.2f} s, run {r['cpu_run_s']:.2f} s "
                         f"({cpu_per_tick[mode][-1]:.2f} ms/tick), close {r['cpu_close_s']:.2f} s; "
                         f"{r['received']} messages, {r['bytes'] / 2**20:.1f} MiB, bad {r['bad']}, snapshots "
                         f"{r['snapshots']} from seq {r['first_seq']}, {r['missed']} missed")
            print(line, flush=True)
    med = {k: float(np.median(v)) for k, v in rows.items()}
    res = {"robots": n_robots, "duration": duration, "run_s": rows, "cpu_ms_per_tick": cpu_per_tick,
           "slowdown_pct": (med["recorded"] / med["plain"] - 1) * 100,
           "slowdown_receive_only_pct": (med["receive only"] / med["plain"] - 1) * 100}
    print(f"N = {n_robots}, {duration:g} s, {repeats} runs each: median run {med['plain']:.2f} s plain, "
          f"{med['receive only']:.2f} s receiving only ({res['slowdown_receive_only_pct']:+.1f} %), "
          f"{med['recorded']:.2f} s recorded ({res['slowdown_pct']:+.1f} %); side process CPU during the run: "
          f"{np.median(cpu_per_tick['receive only']):.2f} ms/tick receiving only, "
          f"{np.median(cpu_per_tick['recorded']):.2f} ms/tick recording")
    return res


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--side-recorder":
        ep, fleet, n, dur, path, mpath, hz, kind = sys.argv[2:10]
        side_recorder(ep, fleet, int(n), float(dur), path, mpath, float(hz), null=kind == "null")
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, nargs="+", default=[37, 500])
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--record-hz", type=float, default=20.0)
    ap.add_argument("--up", action="store_true", help="end to end: swarm up with and without a recorder")
    ap.add_argument("--duration", type=float, default=20.0, help="--up: simulated seconds per run")
    ap.add_argument("--repeats", type=int, default=3, help="--up: runs of each kind")
    a = ap.parse_args()
    if a.up:
        for n in a.robots:
            bench_up(n, a.duration, a.repeats, a.record_hz)
        return
    for n in a.robots:
        r = bench_recorder(n, a.frames, a.record_hz)
        if n == 37:
            for rate, what in ((41.0, "measured (README)"), (100.0, "the issue-3 target")):
                share = r["per_tick_cpu_ms"] * rate / 1e3 * 100
                print(f"  at {rate:g} ticks/s ({what}): {share:.1f} % of one core, {share / 2:.1f} % of 2 cores")


if __name__ == "__main__":
    main()

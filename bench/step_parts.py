"""Where a real-time robot's control period goes inside a running swarm, part by part.

    python bench/step_parts.py [--robots 37] [--duration 20] [--runs 1]

bench/robot_tick.py times one robot alone; in a swarm of 37 processes on 2 cores each period starts
cold (36 other robots, the world and the router ran since), and what a part costs there is not what it
costs alone. This runs `swarm up --mode realtime --no-viz` as a user would, with a `sitecustomize`
module on the robots' path that wraps the parts of a robot's step (agents.robot.Agent's methods, the
compiled calls they make, the drive's send and the bus's put) in a timer on the thread's CPU clock. At
exit each robot writes its sums; this prints, per control period (a call of Agent.tick_realtime) and
averaged over the robots, each part's CPU [us] and calls, indented under the part that calls it.

Figures are inclusive (a part counts the parts under it), and each timer adds its own cost (two reads
of the thread's CPU clock and a Python frame, ~1-3 us cold) to every part above it: the robots' own
"loop CPU" figure, printed beside, grows by about the number of timed calls a period times that.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# (label, depth, where, attribute): where is "Agent", "Guard", "SimDrive", "ZenohBus", "wire" (the compiled
# codec module), "fastlaw" or "drainer" (agents.realtime's drainer: the function it returns is timed)
PARTS = [
    ("Runner work (the whole step)", 0, "Agent", "_step_inline"),
    ("take_poses (the new pose)", 1, "Agent", "take_poses"),
    ("_on_pose (its window)", 2, "Agent", "_on_pose"),
    ("pose_taken (the late-pose deadline)", 2, "Agent", "pose_taken"),
    ("Guard.pose", 2, "Guard", "pose"),
    ("tick_realtime", 1, "Agent", "tick_realtime"),  # its label is the period count's key (main)
    ("_take_inboxes", 2, "Agent", "_take_inboxes"),
    ("drain (10 inboxes, zenoh)", 3, "drainer", ""),
    ("decode_states (compiled)", 3, "wire", "decode_states"),
    ("_on_states -> take_states", 3, "Agent", "_on_states"),
    ("_move_cells", 2, "Agent", "_move_cells"),
    ("_hint_keys", 3, "Agent", "_hint_keys"),
    ("command", 2, "Agent", "command"),
    ("bodies", 3, "Agent", "bodies"),
    ("the law (compiled)", 3, "fastlaw", "robot_command"),
    ("_publish_state", 2, "Agent", "_publish_state"),
    ("_publish", 2, "Agent", "_publish"),
    ("SimDrive.send", 3, "SimDrive", "send"),
    ("ZenohBus.put (state, cmd, status)", 3, "ZenohBus", "put"),
]

SITE = r'''
import atexit, json, os, sys
from time import thread_time

if "robot" in sys.argv and os.environ.get("SWARM_STEP_PARTS"):
    PARTS = json.loads(os.environ["SWARM_STEP_PARTS"])
    OUT = os.environ["SWARM_STEP_PARTS_OUT"]
    sums = {label: [0.0, 0] for label, *_ in PARTS}

    def timed(fn, cell):
        def wrapper(*a, **k):
            c0 = thread_time()
            try:
                return fn(*a, **k)
            finally:
                cell[0] += thread_time() - c0
                cell[1] += 1
        return wrapper

    from agents import guard as guard_mod, realtime, robot
    from swarm.core import fastlaw
    from swarm.drives import sim
    from swarm.net import bus
    from swarm.proto import protocol

    owners = {"Agent": robot.Agent, "Guard": guard_mod.Guard, "SimDrive": sim.SimDrive, "ZenohBus": bus.ZenohBus,
              "wire": protocol._wire, "fastlaw": fastlaw}
    for label, _, where, name in PARTS:
        cell = sums[label]
        if where == "drainer":
            make = realtime.drainer
            realtime.drainer = lambda boxes, make=make, cell=cell: timed(make(boxes), cell)
        elif owners.get(where) is not None:
            setattr(owners[where], name, timed(getattr(owners[where], name), cell))

    @atexit.register
    def _write():
        with open(os.path.join(OUT, f"robot-{os.getpid()}.json"), "w") as f:
            json.dump(sums, f)
'''


def run(robots: int, duration: float, tmp: Path) -> tuple[list[dict], list[float], dict]:
    site, out, logs = tmp / "site", tmp / "out", tmp / "logs"
    for d in (site, out):
        d.mkdir(parents=True, exist_ok=True)
    (site / "sitecustomize.py").write_text(SITE)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)]),
           "SWARM_STEP_PARTS": json.dumps(PARTS), "SWARM_STEP_PARTS_OUT": str(out)}
    p = subprocess.run([sys.executable, "-m", "swarm.cli", "up", "--robots", str(robots), "--mode", "realtime",
                        "--duration", str(duration), "--no-viz", "--quiet", "--metrics", str(tmp / "m.json"),
                        "--log-dir", str(logs)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    if not (tmp / "m.json").exists():
        raise SystemExit(f"step_parts: swarm up exited {p.returncode} without metrics:\n{p.stdout[-2000:]}{p.stderr[-2000:]}")
    got = [json.loads(Path(f).read_text()) for f in glob.glob(str(out / "robot-*.json"))]
    loops = [float(g) for f in glob.glob(str(logs / "robot*.log"))
             for g in re.findall(r"loop CPU (\d+) us a tick", Path(f).read_text())]
    if len(got) != robots:
        raise SystemExit(f"step_parts: {len(got)} robots wrote their sums, expected {robots} (logs in {logs})")
    return got, loops, json.loads((tmp / "m.json").read_text())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=37)
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds a run (default 20)")
    ap.add_argument("--runs", type=int, default=1, help="runs, one after the other; the table is their mean")
    a = ap.parse_args(argv)
    if a.robots < 2 or a.duration <= 0 or a.runs < 1:
        ap.error("--robots must be >= 2, --duration > 0, --runs >= 1")
    rows: dict[str, list[tuple[float, float]]] = {label: [] for label, *_ in PARTS}
    loops = []
    for k in range(a.runs):
        with tempfile.TemporaryDirectory(prefix="swarm-parts-") as tmp:
            got, loop, m = run(a.robots, a.duration, Path(tmp))
        loops += loop
        print(f"run {k + 1}: round trip median {m['round_trip_ms_median']:.2f} ms, p99 {m['round_trip_ms_p99']:.2f} ms, "
              f"collisions {m['collisions']}, robots' loop CPU {statistics.mean(loop):.0f} us a tick (timers in)",
              flush=True)
        for g in got:
            periods = max(1, g["tick_realtime"][1])  # a control period: one call of tick_realtime
            for label in rows:
                s, n = g[label]
                rows[label].append((1e6 * s / periods, n / periods))
    print(f"\nN = {a.robots}, real time, {a.runs} run(s) of {a.duration:g} s; per control period, mean over robots:")
    print(f"{'part':<44} {'CPU us':>8} {'calls':>6}")
    for label, depth, *_ in PARTS:
        us = statistics.mean(r[0] for r in rows[label])
        calls = statistics.mean(r[1] for r in rows[label])
        print(f"{'  ' * depth + label:<44} {us:8.1f} {calls:6.2f}")
    print(f"{'robots loop CPU (their log, timers in)':<44} {statistics.mean(loops):8.1f}")
    never = [label for label in rows if not any(r[1] for r in rows[label])]
    if never:  # renamed, or not on this run's path: the table is wrong where it shows them
        print(f"step_parts: never called in these runs: {', '.join(never)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

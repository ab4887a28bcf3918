"""Lock-step (or real-time) `swarm up` of this tree against another commit, in interleaved pairs.

    python bench/lockstep_ab.py --old HEAD~1 [--robots 37] [--duration 20] [--pairs 6] [--mode realtime]

Checks the other commit out in a temporary git worktree and builds its C modules in place there (the
venv's install of this tree is left alone), then runs `swarm up --mode lockstep --no-viz` of each tree
in turn, `--pairs` times (this tree first in even pairs, the other first in odd ones: the VM's speed drifts
within minutes, and a tree that always ran second would gain or lose by it), so that both see the same
hours of the machine. For each run it prints the
ticks per wall second (the world's steps / run_wall_s) and the mean over robots of the loop and process
CPU a tick that each robot logs at exit ("loop CPU N us a tick, process CPU M us a tick"); then the
medians of each tree and in how many pairs this tree's loop was the cheaper. `--mode realtime` runs at
50 Hz in real time instead and gives the world's round trip (pose out, command back: median and p99 [ms])
in place of ticks/s. docs/performance.md quotes its figures.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LOGGED = re.compile(r"loop CPU (\d+) us a tick, process CPU (\d+) us a tick")


def run(tree: Path, out: Path, robots: int, duration: float, mode: str = "lockstep") -> dict:
    """One run of `tree`'s swarm: ticks/s (lock-step) or the round trip (real time), and the robots' mean
    loop and process CPU a tick."""
    out.mkdir(parents=True)
    env = {**os.environ, "PYTHONPATH": str(tree)}
    p = subprocess.run([sys.executable, "-m", "swarm.cli", "up", "--robots", str(robots), "--mode", mode,
                        "--duration", str(duration), "--no-viz", "--quiet", "--metrics", str(out / "m.json"),
                        "--log-dir", str(out / "logs")], cwd=tree, env=env, capture_output=True, text=True,
                       timeout=600)
    if p.returncode != 0 and not (mode == "realtime" and (out / "m.json").exists()):  # a real-time run
        raise SystemExit(f"lockstep_ab: swarm up in {tree} exited {p.returncode}:\n{p.stdout[-2000:]}{p.stderr[-2000:]}")
    m = json.loads((out / "m.json").read_text())
    logged = [tuple(map(float, g)) for f in (out / "logs").glob("robot*.log") for g in LOGGED.findall(f.read_text())]
    if len(logged) != robots:
        raise SystemExit(f"lockstep_ab: {len(logged)} robot logs with CPU figures in {out / 'logs'}, expected {robots}")
    speed = {"ticks/s": m["steps"] / m["run_wall_s"]} if mode == "lockstep" else \
        {"rt median ms": m["round_trip_ms_median"], "rt p99 ms": m["round_trip_ms_p99"],
         "collisions": m["collisions"]}  # that went wrong says so (swarm up's exit code) and is still measured
    return {**speed, "loop us": statistics.mean(a for a, _ in logged),
            "process us": statistics.mean(b for _, b in logged)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--old", required=True, help="the commit to compare this tree with (e.g. HEAD~1)")
    ap.add_argument("--robots", type=int, default=37)
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds a run (default 20)")
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    a = ap.parse_args(argv)
    if a.robots < 1 or a.duration <= 0 or a.pairs < 1:
        ap.error("--robots and --pairs must be >= 1, --duration > 0")
    with tempfile.TemporaryDirectory(prefix="swarm-ab-") as tmp:
        old = Path(tmp) / "old"
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(old), a.old], cwd=ROOT, check=True)
        try:
            subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=old, check=True,
                           capture_output=True)
            got: dict[str, list[dict]] = {"this tree": [], a.old: []}
            for k in range(a.pairs):
                order = (("this tree", ROOT), (a.old, old))
                for name, tree in order if k % 2 == 0 else order[::-1]:  # ABBA: neither always runs second
                    r = run(tree, Path(tmp) / f"{k}-{len(got[name])}-{name.replace('/', '_')}", a.robots, a.duration, a.mode)
                    got[name].append(r)
                    print(f"pair {k + 1} {name:>12}: " + "  ".join(f"{key} {v:.1f}" for key, v in r.items()), flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(old)], cwd=ROOT, check=False)
    for name, rows in got.items():
        print(f"median {name:>11}: " + "  ".join(f"{key} {statistics.median(r[key] for r in rows):.1f}"
                                                 for key in rows[0]))
    wins = sum(n["loop us"] < o["loop us"] for n, o in zip(got["this tree"], got[a.old]))
    print(f"this tree's loop was the cheaper in {wins} of {a.pairs} pairs")
    return 0


if __name__ == "__main__":
    sys.exit(main())

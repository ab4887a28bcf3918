"""The simulator's speed against another commit's, in the same minutes: for changes of a few per cent.

    python bench/sim_ab.py --old COMMIT [--robots 1000] [--duration 20] [--threads 2] [--rounds 3]

This VM's speed drifts by tens of per cent within minutes, so two runs one after the other cannot tell a 5 %
change. Here both trees run at once, each in a process of its own with its own kernel cache (COMMIT in a
temporary git worktree): the `paper` run of --robots robots, in chunks of 1 simulated s taken in turns, the
order flipped every chunk (the first of a pair ran a steady 4 % faster). Prints each round's wall time of the
kernel for both trees and the ratio of the sums, this tree over COMMIT (below 1: this tree is faster).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from sim_bits import ROOT, build, worktree

WORKER = r"""
import sys, time
from swarm.core import scenario_file as sf
from swarm.core.sim import Simulation
n, duration, threads = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
scn = sf.load("paper", sf.Overrides(robots=n, duration=duration, seed=0), progress=sf.silent)
sim = Simulation(scn, threads=threads)
sim.advance(1)  # compiled or loaded, outside the timing
print("ready", flush=True)
per, k = int(round(1.0 / scn.dt)), 1
for _ in sys.stdin:
    t = time.perf_counter()
    sim.advance(k + per)
    k += per
    print(time.perf_counter() - t, flush=True)
"""


def round_of(trees: dict[str, Path], caches: dict[str, Path], a: argparse.Namespace) -> dict[str, float]:
    """One round: a worker a tree, the chunks in turns; the kernel's wall time of each tree [s]."""
    workers = {}
    try:
        for name, tree in trees.items():
            env = {**os.environ, "PYTHONPATH": str(tree), "SWARM_CACHE_DIR": str(caches[name])}
            workers[name] = subprocess.Popen([sys.executable, "-c", WORKER, str(a.robots), str(a.duration),
                                              str(a.threads)], cwd=tree, env=env, text=True,
                                             stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        for name, w in workers.items():
            assert w.stdout is not None and w.stdout.readline().strip() == "ready", f"{name}: the worker failed"
        spent = dict.fromkeys(trees, 0.0)
        order = list(workers)
        for chunk in range(int(a.duration)):
            for name in order if chunk % 2 == 0 else order[::-1]:
                w = workers[name]
                assert w.stdin is not None and w.stdout is not None
                w.stdin.write("go\n")
                w.stdin.flush()
                spent[name] += float(w.stdout.readline())
        return spent
    finally:
        for w in workers.values():
            if w.stdin is not None:
                w.stdin.close()
            w.wait(timeout=60)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--old", required=True, help="the commit to compare this tree with")
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--duration", type=int, default=20, help="simulated s a round (its chunks)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="swarm-ab-") as tmp, worktree(a.old, Path(tmp)) as old:
        build(ROOT)
        trees = {"this tree": ROOT, a.old: old}
        caches = {name: Path(tmp) / f"cache-{i}" for i, name in enumerate(trees)}
        sums = dict.fromkeys(trees, 0.0)
        print(f"paper, {a.robots} robots, {a.duration} simulated s a round, {a.threads} thread(s)")
        for r in range(a.rounds):
            spent = round_of(trees, caches, a)
            print(f"round {r + 1}: " + "  ".join(f"{name} {s:.3f} s" for name, s in spent.items()), flush=True)
            for name, s in spent.items():
                sums[name] += s
    print(f"this tree / {a.old}: {sums['this tree'] / sums[a.old]:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The simulator's results against another commit's, bit for bit: what a speed change must leave alone.

    python bench/sim_bits.py --old COMMIT      # e.g. the commit before a change to swarm/core

Checks COMMIT out in a temporary git worktree and runs the same cases in both trees, each in a fresh
process with its own kernel cache: `paper` at 37 robots (40 simulated s), 300 (5 s) and 1000 (2 s, with
collisions), `paper-50hz` at 37 (the whole 120 s, governor on). It hashes every recorded sample (poses,
errors, commands, freeze flags, the leader; every step at 37 robots, every 10th above) and the metrics (but
the wall times), prints both trees' hashes and exits 1 when any differs.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CASES = (("paper", 37, 40.0), ("paper", 300, 5.0), ("paper", 1000, 2.0), ("paper-50hz", 37, 120.0))

CASE = r"""
import hashlib, sys
import numpy as np
from swarm.core import scenario_file as sf
from swarm.core.sim import Simulation
name, n, duration = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
scn = sf.load(name, sf.Overrides(robots=n, duration=duration, seed=1), progress=sf.silent)
res = Simulation(scn, record_period=scn.dt * (1 if n < 100 else 10)).run()
r = res.recording
h = hashlib.sha256()
for a in (r.t, r.q, r.err, r.cmd, r.frozen, r.leader):
    h.update(np.ascontiguousarray(a).tobytes())
m = sorted((k, v) for k, v in res.metrics.items() if not k.startswith("wall"))
print(h.hexdigest()[:16], hashlib.sha256(repr(m).encode()).hexdigest()[:16], res.metrics["collisions"])
"""


def run(tree: Path, cache: Path, name: str, n: int, duration: float) -> str:
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(tree), "SWARM_CACHE_DIR": str(cache), "HOME": str(cache)}
    done = subprocess.run([sys.executable, "-c", CASE, name, str(n), str(duration)], cwd=tree, env=env,
                          capture_output=True, text=True, timeout=1800)
    if done.returncode != 0:
        raise SystemExit(f"{tree}: {name} {n}: {done.stderr.strip()[-2000:]}")
    return done.stdout.strip()


def build(tree: Path) -> None:
    """The C modules of `tree`, built in place (setup.py), so both trees run the same kind of robot code."""
    subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=tree, check=True,
                   capture_output=True)


@contextmanager
def worktree(commit: str, tmp: Path) -> Iterator[Path]:
    """COMMIT checked out in a temporary git worktree under tmp, its C modules built; removed afterwards."""
    old = tmp / "old"
    subprocess.run(["git", "worktree", "add", "--detach", "-q", str(old), commit], cwd=ROOT, check=True)
    try:
        build(old)
        yield old
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(old)], cwd=ROOT, check=False)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--old", required=True, help="the commit to compare this tree with")
    a = ap.parse_args(argv)
    differ = 0
    with tempfile.TemporaryDirectory(prefix="swarm-bits-") as tmp, worktree(a.old, Path(tmp)) as old:
        build(ROOT)
        print(f"{'case':22} {'this tree (samples, metrics, collisions)':44} {a.old}")
        for name, n, duration in CASES:
            new = run(ROOT, Path(tmp) / "cache-new", name, n, duration)
            was = run(old, Path(tmp) / "cache-old", name, n, duration)
            same = new == was
            differ += not same
            print(f"{name + ' ' + str(n) + ' ' + format(duration, 'g') + ' s':22} {new:44} {was}"
                  f"{'' if same else '   DIFFERENT'}", flush=True)
    print("the same bits" if not differ else f"{differ} of {len(CASES)} cases differ")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())

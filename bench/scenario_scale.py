"""What building and checking a scenario costs as N grows (grids, not all pairs).

    python bench/scenario_scale.py                     # N = 1 000, 10 000, 100 000
    python bench/scenario_scale.py --robots 1000 20000 --repeats 3

For each N, paper-50hz resized to N robots: the time to build it (hex slots, random starts on a grid,
the checks: Assumption 1, start separations, obstacles, every robot's command at t = 0), the time of
the advisories, the pair checks counted by swarm.core.geometry.Counter (per robot: O(N) stays flat),
then the written file checked again as `swarm scenario check` does (TOML parse included), and the time
and peak memory of refusing a file of 1.8 M poses (counted in its text before it is parsed). Each figure
is the best of --repeats runs in this process, except the refusal, run in a child for its peak RSS.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from swarm.core import scenario_file as sf
from swarm.core.geometry import Counter


def best(repeats: int, fn) -> tuple[float, object]:
    """The least wall time [s] of `repeats` calls of fn, and its last result."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def big_file(path: Path, poses: int) -> None:
    """A scenario file whose pose list holds `poses` entries (about 25 bytes each)."""
    with path.open("w") as f:
        f.write("[run]\nduration = 10.0\ndt = 0.02\n[leader]\nstart = [0.0, 0.0, 0.0]\n"
                "segments = [{duration = 1.0, v = 0.5, w = 0.0}]\n[formation]\n"
                "hex = {count = 100000, spacing = 1.5}\n[robots]\nposes = [\n")
        for i in range(poses):
            f.write(f"[{i % 1000 * 1.1:.3f}, {i // 1000 * 1.1:.3f}, 0.0],\n")
        f.write("]\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, nargs="+", default=[1000, 10_000, 100_000])
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--refusal-poses", type=int, default=1_800_000)
    args = ap.parse_args(argv)
    print(f"{'N':>7} {'build s':>8} {'advice s':>8} {'pairs/N':>8} {'file MB':>8} {'check s':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.robots:
            counter = Counter()
            build_s, scn = best(args.repeats, lambda: sf.load("paper-50hz", sf.Overrides(robots=n), progress=sf.silent,
                                                              counter=counter))
            advice_s, _ = best(args.repeats, lambda: sf.advisories(scn))
            path = Path(tmp) / f"p{n}.toml"
            path.write_text(sf.to_toml(scn))
            check_s, _ = best(args.repeats, lambda: sf.load(str(path), progress=sf.silent))
            print(f"{n:>7} {build_s:>8.3f} {advice_s:>8.3f} {counter.pairs / n / args.repeats:>8.1f} "
                  f"{path.stat().st_size / 1e6:>8.1f} {check_s:>8.3f}", flush=True)
        big = Path(tmp) / "big.toml"
        big_file(big, args.refusal_poses)
        code = ("import resource, sys, time; from swarm.core import scenario_file as sf\n"
                "t = time.perf_counter()\n"
                "try:\n    sf.load(sys.argv[1], progress=sf.silent)\nexcept sf.ScenarioError as e:\n    print(e.reason)\n"
                "print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)\n")
        out = subprocess.run([sys.executable, "-c", code, str(big)], capture_output=True, text=True, timeout=600)
        reason, figures = out.stdout.strip().splitlines()
        took, rss = map(float, figures.split())
        print(f"refusing a {big.stat().st_size / 1e6:.0f} MB file of {args.refusal_poses} poses: {took:.2f} s, "
              f"peak RSS {rss:.0f} MiB ({reason})")
    print(f"this process: peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())

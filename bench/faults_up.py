"""The faults acceptance grid in the distributed runtime: lock-step `swarm up` with 37 robot processes, one
run a case, each compared bit for bit with `swarm sim` of the same case (through `swarm campaign --up`).

    python bench/faults_up.py                          # 37 robots, seed 0, 60 s of paper-50hz a case
    python bench/faults_up.py --duration 120           # the paper's whole run (twice the wall time)
    python bench/faults_up.py --cases kill,hang --robots 19 --duration 30
    python bench/faults_up.py --write                  # also write the table into docs/faults.md
    python bench/faults_up.py --keep out/              # keep every campaign's directory (up.csv, logs)

The cases are bench/faults.py's (its `picks` and `fault_files`: the same robots, the same files), seed 0:
- drop 0.1, drop 0.3, drop 0.5: one drop rule of class "all" (states, poses, commands, references lost
  independently with probability p), one campaign `--drop 0.1,0.3,0.5 --up 3`;
- drop 0.2 burst 10: one drop rule of class "all" with p = 0.2, burst = 10;
- kill: robots 7, 18 and 31 killed at 15 s, no restart (SIGKILL);
- partition: robots 0, 3, ..., 33 with the world and the leader cut from the other 25 from 20 to 22 s;
- hang: robots 3, 16 and 27 stopped at 10 s for 3 s (SIGSTOP, SIGCONT);
- none (only with --cases none,...): no fault.
Each case is one `swarm campaign --seeds 0 ... -j 1 --up K`: `swarm sim` of the case, then the same run as
lock-step `swarm up` (router, world, leader, one process per robot over zenoh on loopback), its trace held
equal to the simulation's recording at every tick (np.array_equal) and its metrics to the simulation's.

The default duration is 60 s, not the paper's 120 s: lock-step `swarm up` with 37 robots runs 30-45 ticks
a second on an idle 2-core machine, so the seven cases take 8-12 minutes at 60 s (3000 ticks each) and
twice that at 120 s; on a 2-core VM shared with other test runs (load 30-40), the seven at 60 s took 20-29
minutes. 60 s holds every fault (the last, the partition, ends at 22 s) and the convergence of the kill,
partition and hang cases; --duration 120 runs the whole paper.

A case that is not identical says where it departs (its first tick and robots) and what `swarm up` said of
its own run: missed commands or robots lost mean the lock-step schedule was not kept (a process went
without CPU for more than the 1 s tick timeout or zenoh's 1 s lease, which a heavily loaded machine
does), so that run was not deterministic; rerun the case (--cases) on a quieter machine. A case that
differs while `swarm up` reports nothing amiss is a bug of the distributed runtime.

Printed: a markdown table (case, what the faults are, identical or the first differing tick and robots,
the wall time of `swarm up` and of `swarm sim`, collisions, convergence) and the campaigns' command lines.
With --write the same block goes between FAULTS_UP_TABLE_START and FAULTS_UP_TABLE_END in docs/faults.md.
Exit 0 when every case is identical, 1 otherwise (the table says which and where), 2 when a campaign
could not run.
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FAULTS_UP_TABLE_START = "<!-- faults-up-table:start -->"
FAULTS_UP_TABLE_END = "<!-- faults-up-table:end -->"
ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "faults.md"
CASES = ("drop 0.1", "drop 0.3", "drop 0.2 burst 10", "kill", "partition", "hang", "drop 0.5")
DROPS = {"none": 0.0, "drop 0.1": 0.1, "drop 0.3": 0.3, "drop 0.5": 0.5}


def _faults_bench():
    """bench/faults.py as a module: its cases, the robots they name, the fault files, the table helpers."""
    spec = importlib.util.spec_from_file_location("bench_faults", Path(__file__).with_name("faults.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


FB = _faults_bench()


def campaigns(chosen: list[str], files: dict[str, Path], n: int) -> list[tuple[str, list[str], list[str]]]:
    """(directory name, the campaign's extra flags, its cases in runs.csv order) for the cases chosen."""
    drops = [c for c in DROPS if c in chosen]
    out = []
    if drops:
        out.append(("drops", ["--drop", ",".join(repr(DROPS[c]) for c in drops)], drops))
    for case, sub, flags in (
            ("drop 0.2 burst 10", "burst", ["--faults", str(files["drop 0.2 burst 10"])]),
            ("kill", "kill", ["--kill", ",".join(f"{i}@15" for i in FB.picks(n)["kill"])]),
            ("partition", "partition", ["--faults", str(files["partition"])]),
            ("hang", "hang", ["--faults", str(files["hang"])])):
        if case in chosen:
            out.append((sub, flags, [case]))
    return out


def read_csv(path: Path) -> list[dict]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def seconds(text: str) -> str:
    return "—" if text == "" else f"{float(text):.1f}"


def converged(text: str) -> str:
    return "not by the end" if text == "" else f"{float(text):g} s"


def identical(up: dict) -> str:
    """yes, or where the run departs from swarm sim and what swarm up said of its own run (missed commands,
    robots lost: the lock-step schedule was not kept, e.g. a process starved of CPU past its 1 s lease)."""
    r = up["result"]
    if r == "identical":
        return "yes"
    said = f"; swarm up reported {up['up_said']}" if up.get("up_said") else "; swarm up reported nothing amiss"
    if r == "differs":
        if up["first_differing_tick"]:
            robots = up["robots_differing"].split()
            shown = ", ".join(robots[:6]) + (f" (+{len(robots) - 6})" if len(robots) > 6 else "")
            return (f"**no**: from tick {up['first_differing_tick']} (t = {float(up['first_differing_t_s']):g} s), "
                    f"robots {shown}; {up['ticks_differing']} ticks differ{said}")
        return f"**no**: {up['why'] or 'the metrics: ' + up['metrics_differing']}{said}"
    return f"**{r}**: {up['why']}"


def table(results: dict[str, tuple[dict, dict]], n: int) -> tuple[list[str], bool]:
    """The markdown table, one row a case (in CASES order), and whether every case was identical."""
    what = {name: text for name, text, _ in FB.cases(n)}
    lines = ["| case | faults | identical to `swarm sim` (every tick, every robot, the metrics) | `swarm up` wall [s] "
             "| `swarm sim` wall [s] | collisions | converged at |",
             "|---|---|---|---:|---:|---:|---:|"]
    ok = True
    for name in [c for c in ("none", *CASES) if c in results]:
        up, run = results[name]
        ok = ok and up["result"] == "identical"
        coll, conv = up["collisions"] or "—", converged(up["converged_at_s"]) if up["up_exit"] == "0" else "—"
        if up["result"] != "identical":  # swarm sim's beside swarm up's
            coll = f"{coll} (sim {run['collisions']})"
            conv = f"{conv} (sim {converged(run['converged_at_s'])})"
        lines.append(f"| {name} | {what[name]} | {identical(up)} | {seconds(up['wallclock.up_s'])} "
                     f"| {seconds(run['wallclock.wall_s'])} | {coll} | {conv} |")
    return lines, ok


def write_docs(path: Path, block: list[str]) -> None:
    """Replace what is between the markers in path with block (the markers stay)."""
    text = path.read_text(encoding="utf-8")
    a, b = text.find(FAULTS_UP_TABLE_START), text.find(FAULTS_UP_TABLE_END)
    if a < 0 or b < a:
        raise SystemExit(f"{path}: the markers {FAULTS_UP_TABLE_START} ... {FAULTS_UP_TABLE_END} are missing")
    path.write_text(text[:a + len(FAULTS_UP_TABLE_START)] + "\n" + "\n".join(block) + "\n" + text[b:],
                    encoding="utf-8")


def bench_command(args: argparse.Namespace) -> str:
    """This bench's command line, with the options that are not the defaults."""
    out = ["python", "bench/faults_up.py"]
    for flag, value, default in (("--scenario", args.scenario, "paper-50hz"), ("--robots", args.robots, 37),
                                 ("--duration", args.duration, 60.0), ("--seed", args.seed, 0),
                                 ("--cases", ",".join(args.cases), ",".join(CASES))):
        if value != default:
            out += [flag, f"{value:g}" if isinstance(value, float) else str(value)]
    return shlex.join(out)


def _cases(text: str) -> list[str]:
    chosen = [c.strip() for c in text.split(",") if c.strip()]
    for c in chosen:
        if c not in ("none", *CASES):
            raise argparse.ArgumentTypeError(f"{c!r} is not a case (the cases: none, {', '.join(CASES)})")
    return chosen


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="paper-50hz")
    ap.add_argument("--robots", type=int, default=37)
    ap.add_argument("--duration", type=float, default=60.0,
                    help="simulated seconds a run (default 60: every fault and most of the convergence; 120: the "
                         "paper's whole run, twice the wall time)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", type=_cases, default=list(CASES), metavar="A,B,...",
                    help=f"the cases to run (default: {', '.join(CASES)}; 'none' adds the run without faults)")
    ap.add_argument("--keep", type=Path, metavar="DIR", help="write every campaign's directory under DIR and keep it")
    ap.add_argument("--write", action="store_true", help="also write the table into docs/faults.md, between "
                                                         f"{FAULTS_UP_TABLE_START} and {FAULTS_UP_TABLE_END}")
    ap.add_argument("--docs", type=Path, default=DOCS, help=f"the file --write writes into (default {DOCS})")
    args = ap.parse_args()

    started = time.perf_counter()
    results: dict[str, tuple[dict, dict]] = {}
    commands = []
    with tempfile.TemporaryDirectory(prefix="swarm-faults-up-") as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        files = FB.fault_files(Path(tmp), args.robots)
        for sub, flags, cases in campaigns(args.cases, files, args.robots):
            out = root / sub
            cmd = [sys.executable, "-m", "swarm.cli", "campaign", "--scenario", args.scenario, "--robots",
                   str(args.robots), "--duration", repr(args.duration), "--seeds", str(args.seed), *flags, "-j", "1",
                   "-o", str(out), "--up", str(len(cases))]
            shown = ["swarm", *cmd[3:]]
            commands.append(shlex.join(Path(c).name if c.endswith(".toml") else c for c in shown[:-4] + shown[-2:]))
            print("$ " + shlex.join(shown), file=sys.stderr, flush=True)
            p = subprocess.run(cmd)
            if p.returncode not in (0, 3):  # 3: a run collided or differs (the table shows it)
                print(f"bench/faults_up.py: swarm campaign exited {p.returncode}", file=sys.stderr)
                return 2
            runs, ups = read_csv(out / "runs.csv"), read_csv(out / "up.csv")
            for case, run, up in zip(cases, runs, ups):
                results[case] = (up, run)
        wall = time.perf_counter() - started
    lines, ok = table(results, args.robots)
    block = ["", *lines, "",
             f"`{args.scenario}` with {args.robots} robots, seed {args.seed}, {args.duration:g} s a run: lock-step "
             f"`swarm up` against `swarm sim` through `swarm campaign --up` (`{bench_command(args)}` at "
             f"{FB.code_version()}: {len(results)} case{'s' if len(results) != 1 else ''} in {wall:.0f} s of wall "
             f"time on {os.cpu_count()} cpus; `swarm sim`'s wall time is its run in the campaign's worker). "
             "The campaigns:", ""]
    block += [f"    {c}" for c in commands]
    block += ["", "(the .toml files as bench/faults.py writes them: its `fault_files`)", ""]
    print("\n".join(block))
    if args.write:
        write_docs(args.docs, block)
        print(f"written into {args.docs}", file=sys.stderr)
    if not ok:
        print("bench/faults_up.py: a case of swarm up is not identical to swarm sim (the table says where)",
              file=sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

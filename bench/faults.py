"""The faults acceptance grid, run through `swarm campaign`, written as a table into docs/faults.md.

    python bench/faults.py                       # paper-50hz, 37 robots, seeds 0-9, -j 2
    python bench/faults.py --seeds 0-2 --robots 19 --no-write   # a quick look, docs left alone
    python bench/faults.py --keep out/           # keep every campaign's directory (plots, index.html)

Cases, each over every seed (`swarm sim` through `swarm campaign`; the robots named are those of 37
robots, `picks` spreads them alike for another --robots):
- none: no fault (the reference);
- drop 0.1, drop 0.3: one drop rule of class "all" (states, poses, commands, references lost
  independently with probability p): `--drop 0,0.1,0.3,0.5`, one campaign for the four drop cases;
- drop 0.2, burst 10: one drop rule of class "all" with p = 0.2, burst = 10 (a --faults file);
- kill: robots 7, 18 and 31 killed at 15 s, no restart (`--kill 7@15,18@15,31@15`);
- partition: robots 0, 3, 6, ..., 33 (12 robots, a third of the swarm, spread through it) in one group with
  the world and the leader, the other 25 in another, from 20 to 22 s (a --faults file);
- hang: robots 3, 16 and 27 hung at 10 s for 3 s (a --faults file);
- drop 0.5: as drop 0.1 (the goal, not the acceptance: zero collisions).

Acceptance (every case but drop 0.5): no run collided and every run converged by the end of its 120 s
(converged_at_s is over the robots alive at the end: a killed robot does not count). For drop 0.5 the
goal is no collision. The table goes between the markers FAULTS_TABLE_START and FAULTS_TABLE_END in
docs/faults.md (the section "Results under faults"), replacing what was there. Exit 0 when every
acceptance case holds, 1 otherwise (the table is written either way), 2 when a campaign could not run.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FAULTS_TABLE_START = "<!-- faults-table:start -->"
FAULTS_TABLE_END = "<!-- faults-table:end -->"
ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "faults.md"



def picks(n: int) -> dict[str, tuple[int, ...]]:
    """The robots each process fault and the partition name, spread through ids 0..n-1 (37 robots: killed
    7, 18, 31; hung 3, 16, 27; partitioned 0, 3, ..., 33, a third of the swarm)."""
    return {"kill": tuple(int(f * n) for f in (0.2, 0.5, 0.85)),
            "hang": tuple(int(f * n) for f in (0.1, 0.45, 0.75)),
            "partition": tuple(range(0, n, 3))[:n // 3]}


def cases(n: int) -> tuple[tuple[str, str, bool], ...]:
    """(case name, what the table says, acceptance (True) or goal (False)), in table order."""
    ids = {k: ", ".join(map(str, v)) for k, v in picks(n).items()}
    return (
        ("none", "no fault (reference)", True),
        ("drop 0.1", "every message lost with p = 0.1 (class all, independent)", True),
        ("drop 0.3", "every message lost with p = 0.3 (class all, independent)", True),
        ("drop 0.2 burst 10", "every message lost with p = 0.2 in bursts of 10 on average (class all)", True),
        ("kill", f"robots {ids['kill']} killed at 15 s (no restart)", True),
        ("partition", f"robots {ids['partition']} (with the world and the leader) cut from the other "
                      f"{n - len(picks(n)['partition'])} from 20 to 22 s", True),
        ("hang", f"robots {ids['hang']} hung at 10 s for 3 s", True),
        ("drop 0.5", "every message lost with p = 0.5 (class all, independent)", False),
    )


def fault_files(d: Path, n: int) -> dict[str, Path]:
    """The --faults files of the cases that need one (no seed: the faults' seed follows each run's)."""
    ids = picks(n)
    files = {
        "drop 0.2 burst 10": "[faults]\n[[faults.drop]]\nclass = \"all\"\np = 0.2\nburst = 10.0\n",
        "partition": f"[faults]\n[[faults.partition]]\ngroups = [[{', '.join(map(str, ids['partition']))}]]\n"
                     "start = 20.0\nend = 22.0\n",
        "hang": "[faults]\n" + "".join(f"[[faults.hang]]\nrobot = {i}\nat = 10.0\nduration = 3.0\n"
                                      for i in ids["hang"]),
    }
    out = {}
    for name, text in files.items():
        out[name] = d / (name.replace(" ", "-") + ".toml")
        out[name].write_text(text)
    return out


def campaigns(files: dict[str, Path], n: int) -> list[tuple[str, list[str], dict[str, str]]]:
    """(directory name, the campaign's extra flags, {case: the drop value of its row in summary.csv})."""
    return [
        ("drops", ["--drop", "0,0.1,0.3,0.5"],
         {"none": "0.0", "drop 0.1": "0.1", "drop 0.3": "0.3", "drop 0.5": "0.5"}),
        ("burst", ["--faults", str(files["drop 0.2 burst 10"])], {"drop 0.2 burst 10": "0.0"}),
        ("kill", ["--kill", ",".join(f"{i}@15" for i in picks(n)["kill"])], {"kill": "0.0"}),
        ("partition", ["--faults", str(files["partition"])], {"partition": "0.0"}),
        ("hang", ["--faults", str(files["hang"])], {"hang": "0.0"}),
    ]


def read_csv(path: Path) -> list[dict]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def num(text: str, digits: int = 3) -> str:
    if text == "":
        return "—"
    return f"{float(text):.{digits}g}" if abs(float(text)) < 1 else f"{float(text):.{digits}f}".rstrip("0").rstrip(".")


def table(results: dict[str, tuple[dict, list[dict]]], seeds: int, n: int) -> tuple[list[str], bool]:
    """The markdown table (one row a case) and whether every acceptance case held."""
    lines = [f"| case | faults | collided runs | converged runs (of {seeds}) | convergence median (min-max) [s] "
             "| smallest robot distance [m] | smallest obstacle distance [m] | final position error, median (max) [m] "
             "| robots alive at the end (min) | messages dropped (median) | |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    ok = True
    for name, what, acceptance in cases(n):
        s, runs = results[name]
        collided = int(s["collided_runs"])
        converged = int(s["converged_runs"])
        failed = int(s["failed_runs"])
        held = collided == 0 and failed == 0 and (converged == len(runs) or not acceptance)
        if acceptance:
            ok = ok and held
            verdict = "pass" if held else "FAIL"
        else:
            verdict = "goal met" if held else "goal not met"
        names = [f"seed {r['seed']}" for r in runs if r["collisions"] not in ("", "0")]
        coll = f"{collided} ({', '.join(names)})" if names else str(collided)
        stuck = [f"seed {r['seed']}" for r in runs if r["converged_at_s"] == "" and r["failure"] == ""]
        conv = f"{converged} (not: {', '.join(stuck)})" if stuck and len(stuck) < len(runs) else str(converged)
        lo, hi = num(s["converged_at_s_min"], 4), num(s["converged_at_s_max"], 4)
        spread = "—" if s["converged_at_s_median"] == "" else f"{num(s['converged_at_s_median'], 4)} ({lo}-{hi})"
        lines.append(f"| {name} | {what} | {coll} | {conv} | {spread} | {num(s['min_robot_distance_m_min'])} "
                     f"| {num(s['min_obstacle_distance_m_min'])} | {num(s['final_position_error_max_m_median'], 2)} "
                     f"({num(s['final_position_error_max_m_max'], 2)}) | {s['robots_alive_at_end_min'] or runs[0]['robots']} "
                     f"| {float(s['messages_dropped_median']):.0f} | {verdict} |")
    return lines, ok


def code_version() -> str:
    """The commit the bench runs (this checkout's, "-dirty" with uncommitted changes), or "an unknown commit"."""
    try:
        p = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty", "--abbrev=7"],
                           capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return "an unknown commit"
    return f"commit {p.stdout.strip()}" if p.returncode == 0 and p.stdout.strip() else "an unknown commit"


def write_docs(path: Path, block: list[str]) -> None:
    """Replace what is between the markers in path with block (the markers stay)."""
    text = path.read_text(encoding="utf-8")
    a, b = text.find(FAULTS_TABLE_START), text.find(FAULTS_TABLE_END)
    if a < 0 or b < a:
        raise SystemExit(f"{path}: the markers {FAULTS_TABLE_START} ... {FAULTS_TABLE_END} are missing")
    path.write_text(text[:a + len(FAULTS_TABLE_START)] + "\n" + "\n".join(block) + "\n" + text[b:], encoding="utf-8")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="paper-50hz")
    ap.add_argument("--robots", type=int, default=37)
    ap.add_argument("--seeds", default="0-9", help="as swarm campaign --seeds (default 0-9)")
    ap.add_argument("-j", "--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--keep", type=Path, metavar="DIR", help="write every campaign's directory under DIR and keep it")
    ap.add_argument("--no-write", action="store_true", help="print the table, leave docs/faults.md alone")
    ap.add_argument("--docs", type=Path, default=DOCS, help=f"the file to write the table into (default {DOCS})")
    args = ap.parse_args()

    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="swarm-faults-") as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        files = fault_files(Path(tmp), args.robots)
        results: dict[str, tuple[dict, list[dict]]] = {}
        commands = []
        for sub, flags, rows_of in campaigns(files, args.robots):
            out = root / sub
            cmd = [sys.executable, "-m", "swarm.cli", "campaign", "--scenario", args.scenario, "--robots",
                   str(args.robots), "--seeds", args.seeds, *flags, "-j", str(args.jobs), "-o", str(out)]
            shown = ["swarm", *cmd[3:]]
            commands.append(" ".join(Path(c).name if c.endswith(".toml") else c for c in shown[:-2]))
            print("$ " + " ".join(shown), file=sys.stderr, flush=True)
            p = subprocess.run(cmd)
            if p.returncode not in (0, 3):  # 3: a run collided (the table shows it)
                print(f"bench/faults.py: swarm campaign exited {p.returncode}", file=sys.stderr)
                return 2
            summary = {s["drop"]: s for s in read_csv(out / "summary.csv")}
            runs = read_csv(out / "runs.csv")
            for case, drop in rows_of.items():
                results[case] = (summary[drop], [r for r in runs if r["drop"] == drop])
        wall = time.perf_counter() - started
        seeds = len(results["none"][1])
        lines, ok = table(results, seeds, args.robots)
    block = ["", *lines, "",
             f"`{args.scenario}` with {args.robots} robots, seeds {args.seeds}, 120 s each, in `swarm sim` through "
             f"`swarm campaign` (`python bench/faults.py` at {code_version()}: "
             f"{sum(len(r) for _, r in results.values())} runs in {wall:.0f} s of wall time with -j {args.jobs} on "
             f"{os.cpu_count()} cpus). The campaigns:", ""]
    block += [f"    {c}" for c in commands]
    block += ["", "(the .toml files as the bench writes them: its docstring and `fault_files`)", ""]
    print("\n".join(block))
    if not args.no_write:
        write_docs(args.docs, block)
        print(f"written into {args.docs}", file=sys.stderr)
    if not ok:
        print("bench/faults.py: an acceptance case failed (FAIL in the table)", file=sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

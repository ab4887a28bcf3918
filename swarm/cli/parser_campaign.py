"""The parser of `swarm campaign` (swarm.cli.parser puts it in the `swarm` parser)."""

from __future__ import annotations

import argparse
from pathlib import Path

from swarm.cli.flags import (
    Joined,
    add_violation_flag,
    count_arg,
    drop_list,
    positive_float,
    seed_list,
)


def add_campaign_parser(sub) -> None:
    c = sub.add_parser(
        "campaign", help="swarm sim over a grid of seeds and drop probabilities, on every core: CSV, plots, a page; "
                         "--up N: its first N runs again as lock-step swarm up, each held equal to its simulation",
        description="Run swarm sim for every seed of --seeds and every probability of --drop, in -j worker "
                    "processes, with a progress bar and an ETA. A seed sets run.seed and the faults' seed with it "
                    "(unless the faults set one); each p adds one drop rule of class all to the faults of the "
                    "scenario or of --faults FILE (0: none). Writes DIR/runs.csv (one row a run), DIR/summary.csv "
                    "(one row per p), DIR/campaign.json (its flags), convergence.png, distance.png, error.png and "
                    "DIR/index.html. The same command writes the same rows (the wallclock.* columns aside). Exit 3 "
                    "when a run collided (it names the runs); a run that did not converge is reported, not a failure. "
                    "With --up N, the first N rows of runs.csv then run again, one at a time, as lock-step swarm up "
                    "(--trace, the same scenario, seed, drop and faults), each compared with swarm sim tick for "
                    "tick, bit for bit, and on its metrics: one line a row, DIR/up.csv, exit 3 when one differs or "
                    "its swarm up failed. --up N --from DIR does that for a campaign already run "
                    "(docs/faults.md, Campaigns).",
        epilog="Examples: swarm campaign --scenario paper-50hz --seeds 0-9 --drop 0,0.1,0.3 -o out/ | "
               "swarm campaign --scenario paper-50hz --seeds 0-9 --faults kills.toml -j 2 -o kills/ | "
               "swarm campaign --seeds 0-1 --drop 0.3,0 --kill 7@15 -o out/ --up 2 | "
               "swarm campaign --up 4 --from out/")
    g = c.add_argument_group("the grid")
    g.add_argument("--scenario", metavar="NAME|FILE",
                   help="built-in name (paper, paper-50hz, turtlebot3) or a TOML file (default: paper-50hz)")
    g.add_argument("--seeds", type=seed_list, metavar="A-B",
                   help="the seeds: A-B (both included), A, or a comma list of those (e.g. 0-9); required "
                        "unless --from")
    g.add_argument("--drop", type=drop_list, metavar="P1,P2,...",
                   help="drop probabilities: each adds one drop rule of class all (every message) to the faults; "
                        "0: no rule (default: 0 only)")
    g = c.add_argument_group("every run (a flag beats the scenario file, which beats the built-in default)")
    g.add_argument("--robots", type=count_arg, metavar="N", help="number of robots (resizes built-in and generated scenarios)")
    g.add_argument("--duration", type=positive_float, metavar="T",
                   help="simulated seconds to run (default: the scenario's run.duration)")
    g.add_argument("--dt", type=positive_float, metavar="DT", help="control period [s]")
    g.add_argument("--governor", action=argparse.BooleanOptionalAction, default=None,
                   help="the discrete-time safety governor (default: the scenario's control.governor)")
    g.add_argument("--faults", metavar="FILE",
                   help="a TOML file holding a [faults] table: it replaces the scenario's in every run; the --drop "
                        "rule is added to it")
    g.add_argument("--kill", metavar="ID@T,...", action=Joined,
                   help="kill robot ID's process at T s in every run (e.g. 2@15,5@15; repeatable)")
    g = c.add_argument_group("output")
    g.add_argument("-o", "--out", type=Path, metavar="DIR",
                   help="the directory to write (made if missing; its files of a campaign are replaced); required "
                        "unless --from")
    g.add_argument("-j", "--jobs", type=count_arg, metavar="JOBS", help="worker processes (default: every core)")
    g.add_argument("--cluster", metavar="ADDRESS",
                   help="run the runs on a Dask cluster instead of local workers: tcp://HOST:PORT (a `dask scheduler` "
                        "with `dask worker`s on any machines that have swarm installed) or local:N (N worker "
                        "processes here); a lost worker's runs run again on another; needs pip install "
                        "'swarm[cluster]' (docs/faults.md, Campaigns on a cluster)")
    g.add_argument("--quiet", action="store_true", help="no progress bar and no summary table")
    add_violation_flag(g)
    g = c.add_argument_group("the distributed runtime against the simulator (lock-step swarm up)")
    g.add_argument("--up", type=count_arg, metavar="N",
                   help="then run the first N rows of runs.csv again as lock-step swarm up, one at a time (each "
                        "bounded by a timeout from its size; logs in DIR/up/row-K/), and compare each with swarm "
                        "sim: every robot's pose at every tick, bit for bit, and the metrics; writes DIR/up.csv; "
                        "exit 3 when one differs or fails")
    g.add_argument("--from", dest="from_dir", type=Path, metavar="DIR",
                   help="with --up N: check a campaign already run in DIR (its campaign.json and runs.csv) instead "
                        "of running a grid; no grid flag, -o or -j with it")
    c.set_defaults(func="swarm.cli.campaign:cmd_campaign")

"""`swarm campaign` through the real command line: the files it writes, rows that repeat, rows equal to
`swarm sim`, bad input refused (exit 2), collisions (exit 3); --up: rows run again as lock-step `swarm up`
(real processes over zenoh on loopback, bounded by the command's own timeouts) and held equal to `swarm sim`."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

SMALL = ["--scenario", "paper-50hz", "--robots", "7", "--duration", "20"]
COLLIDE = ("[run]\nduration = 10.0\ndt = 0.25\n[control]\ngovernor = false\n[bodies]\nr = 0.3\nR = 0.4\n"
           "[leader]\nstart = [0.0, 0.0, 0.0]\nsegments = [{ duration = 10.0, v = 2.0, w = 0.0 }]\n"
           "[formation]\noffsets = [[0.0, 0.0]]\n[robots]\nposes = [[0.0, 0.0, 0.0]]\n"
           "[[obstacles]]\ncenter = [5.1, 0.0]\n")  # one robot driven at 2 m/s through an obstacle


def swarm(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm.cli", *args], capture_output=True, text=True, timeout=timeout)


def read_csv(path: Path) -> tuple[list[str], list[dict]]:
    with path.open(newline="") as f:
        r = csv.DictReader(f)
        return list(r.fieldnames), list(r)


def without_wall_clock(cols: list[str], rows: list[dict]) -> list[list[str]]:
    return [[r[c] for c in cols if not c.startswith("wallclock.")] for r in rows]


def flat(m: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in m.items():
        out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
    return out


def cell(v) -> str:
    """A metric as runs.csv writes it."""
    return "" if v is None else ("true" if v else "false") if isinstance(v, bool) else repr(v) if isinstance(v, float) \
        else str(v)


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("campaign") / "out"
    p = swarm("campaign", *SMALL, "--seeds", "0-1", "--drop", "0,0.3", "-j", "2", "-o", str(out))
    assert p.returncode == 0, p.stderr
    assert "did not converge" in p.stdout and "not a failure" in p.stdout  # 20 s is too short for 7 robots
    return out


@pytest.mark.timeout(180)
def test_a_campaign_writes_every_file_with_the_grid_values(small):
    for name in ("runs.csv", "summary.csv", "index.html", "convergence.png", "distance.png", "error.png"):
        assert (small / name).stat().st_size > 0, name
    for name in ("convergence.png", "distance.png", "error.png"):
        data = (small / name).read_bytes()
        assert data.startswith(b"\x89PNG") and len(data) > 10_000, name
    cols, rows = read_csv(small / "runs.csv")
    assert cols[:3] == ["scenario", "seed", "drop"]
    assert cols[-1] == "wallclock.wall_s" and "wall_s" not in cols and "failure" in cols
    assert [(r["scenario"], r["seed"], r["drop"]) for r in rows] == [
        ("paper-50hz", "0", "0.0"), ("paper-50hz", "1", "0.0"), ("paper-50hz", "0", "0.3"), ("paper-50hz", "1", "0.3")]
    for r in rows:
        assert r["robots"] == "7" and r["duration_s"] == "20.0" and r["failure"] == "" and r["collisions"] == "0"
        dropping = r["drop"] == "0.3"
        assert (int(r["messages_dropped"]) > 0) == dropping
        assert (r["faults.dropped.state"] != "") == dropping  # the faults object, flattened, under faults only
        assert r["robots_alive_at_end"] == "7"  # without faults too: every robot
        assert float(r["wallclock.wall_s"]) > 0
    scols, summ = read_csv(small / "summary.csv")
    assert [s["drop"] for s in summ] == ["0.0", "0.3"] and all(s["runs"] == "2" for s in summ)
    for s in summ:
        mine = [r for r in rows if r["drop"] == s["drop"]]
        assert int(s["converged_runs"]) + int(s["not_converged_runs"]) == 2
        assert int(s["not_converged_runs"]) == sum(1 for r in mine if r["converged_at_s"] == "")
        assert float(s["min_robot_distance_m_min"]) == min(float(r["min_robot_distance_m"]) for r in mine)
        assert s["collided_runs"] == "0" and s["robots_alive_at_end_min"] == "7"
    page = (small / "index.html").read_text()
    assert "swarm campaign --scenario paper-50hz --seeds 0-1 --drop 0.0,0.3 --robots 7 --duration 20.0" in page
    for name in ("convergence.png", "distance.png", "error.png", "summary.csv", "runs.csv"):
        assert f"src='{name}'" in page or f"href='{name}'" in page, name
    assert "min_robot_distance_m_min" in page and "did not converge" in page
    assert "swarm sim --scenario paper-50hz --seed 1 --robots 7 --duration 20.0 --drop 0.3" in page  # the replay


@pytest.mark.timeout(180)
def test_the_same_campaign_writes_the_same_rows(small, tmp_path):
    again = tmp_path / "again"
    p = swarm("campaign", *SMALL, "--seeds", "0-1", "--drop", "0,0.3", "-j", "1", "-o", str(again), "--quiet")
    assert p.returncode == 0, p.stderr
    for name in ("runs.csv", "summary.csv"):
        cols, rows = read_csv(small / name)
        cols2, rows2 = read_csv(again / name)
        assert cols == cols2, name
        assert without_wall_clock(cols, rows) == without_wall_clock(cols2, rows2), name
        walls = [c for c in cols if c.startswith("wallclock.")]
        assert walls, name  # kept, marked


@pytest.mark.timeout(180)
def test_a_row_is_what_swarm_sim_writes(small, tmp_path):
    m = tmp_path / "m.json"
    p = swarm("sim", *SMALL, "--seed", "1", "--drop", "0.3", "--metrics", str(m), "--quiet")
    assert p.returncode == 0, p.stderr
    cols, rows = read_csv(small / "runs.csv")
    row = next(r for r in rows if r["seed"] == "1" and r["drop"] == "0.3")
    for k, v in flat(json.loads(m.read_text())).items():
        if k != "wall_s":
            assert row[k] == cell(v), k


@pytest.mark.timeout(180)
def test_the_faults_seed_follows_the_run_and_the_drop_rule_adds_to_the_file(tmp_path):
    faults = tmp_path / "f.toml"
    faults.write_text("[faults]\n[[faults.drop]]\nclass = \"state\"\np = 0.2\nburst = 4.0\n"
                      "[[faults.kill]]\nrobot = 3\nat = 5.0\n")
    out = tmp_path / "out"
    p = swarm("campaign", *SMALL, "--seeds", "2-3", "--faults", str(faults), "--drop", "0,0.1", "-o", str(out),
              "-j", "2", "--quiet")
    assert p.returncode == 0, p.stderr
    _, rows = read_csv(out / "runs.csv")
    assert [(r["seed"], r["drop"]) for r in rows] == [("2", "0.0"), ("3", "0.0"), ("2", "0.1"), ("3", "0.1")]
    assert all(r["faults.killed"] == "1" and r["robots_alive_at_end"] == "6" for r in rows)
    for seed, drop, extra in (("3", "0.0", []), ("3", "0.1", ["--drop", "0.1"])):
        m = tmp_path / f"m{seed}{drop}.json"
        q = swarm("sim", *SMALL, "--seed", seed, "--faults", str(faults), *extra, "--metrics", str(m), "--quiet")
        assert q.returncode == 0, q.stderr
        row = next(r for r in rows if r["seed"] == seed and r["drop"] == drop)
        assert {k: row[k] for k in flat(json.loads(m.read_text())) if k != "wall_s"} == \
            {k: cell(v) for k, v in flat(json.loads(m.read_text())).items() if k != "wall_s"}
    assert next(r for r in rows if r["seed"] == "3" and r["drop"] == "0.1")["faults.dropped.pose"] != "0"
    assert next(r for r in rows if r["seed"] == "3" and r["drop"] == "0.0")["faults.dropped.pose"] == "0"


@pytest.mark.timeout(240)
@pytest.mark.parametrize("args, said", [
    (["--seeds", "3-1"], "argument --seeds: '3-1': a range A-B needs 0 <= A <= B"),
    (["--seeds", "x"], "'x' is not a seed"),
    (["--seeds", "0-2,1"], "seed 1 is given twice"),
    (["--seeds", "0", "--drop", "0.1,1.5"], "'1.5': a probability is in [0, 1]"),
    (["--seeds", "0", "--drop", "0.1,0.10"], "the probability 0.1 is given twice"),
    (["--seeds", "0", "-j", "0"], "--jobs: must be >= 1"),
    (["--seeds", "0", "--robots", "0"], "--robots: must be >= 1"),
    (["--seeds", "0", "--scenario", "nope"], "nope: no such file"),
    (["--seeds", "0", "--faults", "missing.toml"], "missing.toml: no such file"),
    (["--seeds", "0", "--faults", "BAD"], "faults.drop[0].p"),
    (["--seeds", "0", "--kill", "7@5"], "--kill '7@5': robot 7 is not in the scenario"),
    (["--seeds", "0", "--duration", "4", "--kill", "2@5"], "is not before the end of the run"),
    (["--seeds", "0", "-o", "FILE"], "exists and is not a directory"),
    (["--seeds", "0", "-o", "nowhere/out"], "does not exist"),
])
def test_bad_input_is_refused_before_any_run(tmp_path, args, said):
    bad = tmp_path / "bad.toml"
    bad.write_text("[faults]\n[[faults.drop]]\nclass = \"all\"\np = 2.0\n")
    (tmp_path / "a-file").write_text("")
    args = [str(bad) if a == "BAD" else str(tmp_path / "a-file") if a == "FILE" else
            str(tmp_path / a) if a in ("missing.toml", "nowhere/out") else a for a in args]
    out = tmp_path / "out"
    if "-o" not in args:
        args += ["-o", str(out)]
    base = list(SMALL)
    for flag in set(args) & set(base[::2]):  # a flag the case sets itself (a flag given twice is refused)
        at = base.index(flag)
        del base[at:at + 2]
    p = swarm("campaign", *base, *args)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert said in p.stderr, p.stderr
    assert not out.exists()  # refused before anything was written


@pytest.mark.timeout(180)
def test_a_collision_exits_3_naming_the_runs(tmp_path):
    scn = tmp_path / "collide.toml"
    scn.write_text(COLLIDE)
    out = tmp_path / "out"
    p = swarm("campaign", "--scenario", str(scn), "--seeds", "0-1", "--drop", "0,0.3", "-j", "2", "-o", str(out))
    assert p.returncode == 3, p.stderr
    assert "4 runs failed a check" in p.stderr
    for run in ("seed 0 drop 0 (", "seed 1 drop 0 (", "seed 0 drop 0.3 (", "seed 1 drop 0.3 ("):
        assert run in p.stderr, run
    _, rows = read_csv(out / "runs.csv")
    assert all(int(r["collisions"]) >= 1 for r in rows)
    _, summ = read_csv(out / "summary.csv")
    assert [s["collided_runs"] for s in summ] == ["2", "2"]
    assert "collided: " in (out / "index.html").read_text()
    p = swarm("campaign", "--scenario", str(scn), "--seeds", "0", "-o", str(out), "--allow-violations", "--quiet")
    assert p.returncode == 0, p.stderr
    _, rows = read_csv(out / "runs.csv")
    assert [(r["seed"], r["drop"]) for r in rows] == [("0", "0.0")]  # the files of the last campaign only


# --------------------------------------------------------------------------- --up: swarm up against swarm sim

UP = ["--scenario", "paper-50hz", "--robots", "7", "--duration", "10", "--seeds", "0-1", "--drop", "0.3,0",
      "--kill", "3@5"]  # grid order: drop 0.3 first, so --up 2 checks both seeds under drops and a kill


@pytest.fixture(scope="module")
def checked(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    out = tmp_path_factory.mktemp("up") / "out"
    return out, swarm("campaign", *UP, "-j", "2", "-o", str(out), "--up", "2", timeout=420)


def up_logs(out: Path) -> str:
    return "".join(f"\n--- {p}\n{p.read_text(errors='replace')[-2000:]}" for p in sorted(out.glob("up/row-*/**/*.log")))


def worst_first(p: subprocess.CompletedProcess) -> str:
    """The lines of the rows that did not check, first (a failure's summary shows only the first line)."""
    bad = [ln for ln in p.stdout.splitlines() if ln.startswith("up ") and ("DIFFERS" in ln or "FAILED" in ln)]
    return "\n".join(bad + [p.stdout + p.stderr])


@pytest.mark.timeout(480)
def test_up_reruns_the_first_rows_as_lockstep_swarm_up_identical_to_swarm_sim(checked):
    out, p = checked
    assert p.returncode == 0, worst_first(p) + up_logs(out)
    said = [line for line in p.stdout.splitlines() if line.startswith("up ")]
    assert [s.split(":")[0] for s in said] == ["up 1/2, seed 0 drop 0.3", "up 2/2, seed 1 drop 0.3"], p.stdout
    assert all(": OK, identical to swarm sim" in s and "swarm up " in s and "swarm sim " in s for s in said), said
    assert "2 of 2 swarm up runs identical to swarm sim" in p.stdout
    _, runs = read_csv(out / "runs.csv")
    cols, rows = read_csv(out / "up.csv")
    assert cols[:5] == ["row", "scenario", "seed", "drop", "result"] and cols[-2:] == ["wallclock.up_s", "wallclock.sim_s"]
    assert [(r["row"], r["seed"], r["drop"], r["result"]) for r in rows] == [
        ("1", "0", "0.3", "identical"), ("2", "1", "0.3", "identical")]
    for r, run in zip(rows, runs):
        assert r["up_exit"] == "0" and r["first_differing_tick"] == "" and r["ticks_differing"] == "0"
        # swarm up's own metrics, as swarm sim's in runs.csv: the kill happened, messages were dropped
        for k in ("collisions", "converged_at_s", "min_robot_distance_m", "robots_alive_at_end", "messages_dropped"):
            assert r[k] == run[k], k
        assert r["robots_alive_at_end"] == "6" and int(r["messages_dropped"]) > 0
        for flag in ("swarm up --scenario paper-50hz --seed", "--robots 7", "--duration 10.0", "--kill 3@5",
                     "--drop 0.3", "--mode lockstep", "--trace", "--no-viz", "--quiet"):
            assert flag in r["command"], flag
        row_dir = out / r["files"]
        assert "robot 3 killed (SIGKILL" in (row_dir / "logs" / "faults.log").read_text()  # a real kill
        assert (row_dir / "logs" / "world.log").is_file() and not (row_dir / "trace.npz").exists()  # kept if it differs
    page = (out / "index.html").read_text()
    assert "Lock-step swarm up against swarm sim (2 of 2 identical)" in page and "href='up.csv'" in page
    flags = json.loads((out / "campaign.json").read_text())
    assert flags["scenario"] == "paper-50hz" and flags["seeds"] == [0, 1] and flags["drop"] == [0.3, 0.0]
    assert flags["kill"] == "3@5" and flags["robots"] == 7 and flags["duration"] == 10.0


@pytest.mark.timeout(240)
def test_up_from_a_campaign_whose_rows_no_longer_match_swarm_sim_says_stale_without_running_swarm_up(checked,
                                                                                                      tmp_path):
    out, p = checked
    assert p.returncode == 0, p.stderr
    copy = tmp_path / "copy"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("up", "up.csv"))
    cols, rows = read_csv(copy / "runs.csv")
    rows[0]["min_robot_distance_m"] = repr(float(rows[0]["min_robot_distance_m"]) + 1e-12)  # as if the file changed
    with (copy / "runs.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, cols, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    earlier = copy / "up" / "row-2"  # the files of an earlier check of two rows: up.csv will list one
    earlier.mkdir(parents=True)
    (earlier / "up.log").write_text("an earlier check's\n")
    q = swarm("campaign", "--up", "1", "--from", str(copy), "--quiet")
    assert q.returncode == 3, q.stdout + q.stderr
    assert not earlier.exists()
    assert "up 1/1, seed 0 drop 0.3: STALE" in q.stdout and "min_robot_distance_m" in q.stdout
    assert "seed 0 drop 0.3 stale" in q.stderr
    _, up = read_csv(copy / "up.csv")
    assert [(r["row"], r["result"], r["up_exit"]) for r in up] == [("1", "stale", "")]
    assert not (copy / "up" / "row-1").exists()  # no swarm up was started


@pytest.mark.timeout(240)
@pytest.mark.parametrize("args, said", [
    (["--seeds", "0-1", "--up", "0"], "argument --up: must be >= 1, got '0'"),
    (["--seeds", "0-1", "--up", "3"], "--up 3: the grid has 2 runs (2 seeds x 1 drop probabilities)"),
    (["--up", "5", "--from", "DONE"], "runs.csv has 4 runs"),
    (["--from", "DONE"], "give --up N"),
    (["--up", "1", "--from", "DONE", "--seeds", "0", "-j", "2"], "--seeds, -j cannot be given with it"),
    (["--up", "1", "--from", "EMPTY"], "campaign.json is missing: not a campaign directory"),
    (["-o", "OUT"], "--seeds is required"),
])
def test_bad_up_input_is_refused_before_anything_runs(checked, tmp_path, args, said):
    out, _ = checked
    (tmp_path / "empty").mkdir()
    before = (out / "up.csv").read_bytes()
    args = [str(out) if a == "DONE" else str(tmp_path / "empty") if a == "EMPTY" else str(tmp_path / "out")
            if a == "OUT" else a for a in args]
    if "--from" not in args and "-o" not in args:
        args += ["-o", str(tmp_path / "out")]
    p = swarm("campaign", "--robots", "7", "--duration", "10", *args) if "--from" not in args else \
        swarm("campaign", *args)
    assert p.returncode == 2, (p.returncode, p.stdout, p.stderr)
    assert said in p.stderr, p.stderr
    assert not (tmp_path / "out").exists() and (out / "up.csv").read_bytes() == before

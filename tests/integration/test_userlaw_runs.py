"""A law of one's own end to end (docs/control.md): `swarm sim` and lock-step `swarm up` give the same run with
and without faults; a law that raises ends the run naming itself, the robot and the step; swarm.simulate is
`swarm sim` from Python."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.integration.helpers import up

EXAMPLES = Path(__file__).parents[2] / "examples"
SMALL = ("--robots", "5", "--duration", "4")


def sim_metrics(tmp_path: Path, *args: str) -> dict:
    out = tmp_path / "sim.json"
    done = subprocess.run([sys.executable, "-m", "swarm.cli", "sim", *args, "--quiet", "--metrics", str(out)],
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    return json.loads(out.read_text())


def same_run(a: dict, b: dict) -> None:
    keys = set(a) & set(b) - {"wall_s", "mode"}
    assert {k: a[k] for k in keys} == {k: b[k] for k in keys}


@pytest.mark.integration
@pytest.mark.parametrize("faults", [(), ("--drop", "0.3")], ids=["no-faults", "drop-0.3"])
def test_lockstep_up_equals_sim_with_a_law_of_ones_own(tmp_path, faults):
    scenario = ("--scenario", str(EXAMPLES / "goto_slot.toml"), *SMALL, *faults)
    expected = sim_metrics(tmp_path, *scenario)
    cmd, metrics = up(tmp_path, *scenario, "--quiet")
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    logs = "".join(p.read_text() for p in (tmp_path / "logs").glob("robot-*.log"))
    assert done.returncode == 0, done.stderr + logs
    assert "laws/goto_slot.py:goto_slot (compiled by numba)" in logs or "goto_slot.py:goto_slot (compiled by numba)" in logs
    m = json.loads(metrics.read_text())
    same_run(expected, m)
    assert m["mode"] == "lockstep" and m["collisions"] == 0 and m["freeze_intervals"] == 0


def failing_law(tmp_path: Path, k1: float) -> tuple[Path, subprocess.CompletedProcess]:
    """examples/goto_slot.toml with laws/fail.py:fail, a law that moves at 0.1 m/s until t = 1 s, then raises
    ValueError (params[0] = k1 > 0.25) or returns v = inf; and the `swarm sim` run of it. One law for both cases:
    numba compiles it once (its cache is per law file and name)."""
    (tmp_path / "laws").mkdir()
    (tmp_path / "laws" / "fail.py").write_text(
        "def fail(me, ref, bodies, params, *, t):\n"
        "    if t >= 1.0 and me[0] > -1e9:\n"
        "        if params[0] > 0.25:\n"
        "            raise ValueError('too late')\n"
        "        return float('inf'), 0.0\n"
        "    return 0.1, 0.0\n")
    scn = tmp_path / "fail.toml"
    text = (EXAMPLES / "goto_slot.toml").read_text().replace("laws/goto_slot.py:goto_slot", "laws/fail.py:fail")
    scn.write_text(text.replace("params = [0.5,", f"params = [{k1},"))
    return scn, subprocess.run([sys.executable, "-m", "swarm.cli", "sim", "--scenario", str(scn), *SMALL, "--quiet"],
                               capture_output=True, text=True, timeout=240)


@pytest.mark.integration
def test_a_law_that_raises_ends_the_run_naming_the_law_the_robot_and_the_step(tmp_path):
    scn, done = failing_law(tmp_path, 0.5)
    assert done.returncode == 1, done.stderr
    assert "the law 'laws/fail.py:fail' raised ValueError: too late for robot 0 at step 50 (t = 1 s)" in done.stderr
    # swarm up: the robots' processes stop with that line (never restarted) and the run ends with it
    cmd, metrics = up(tmp_path, "--scenario", str(scn), *SMALL, "--quiet")
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    assert done.returncode == 1, done.stderr
    said = re.search(r"robot \d refused to go on \(robot (\d): the law '(\S+)' raised ValueError: too late at step 50 "
                     r"\(t = 1 s\); log: ", done.stderr + done.stdout)
    assert said and said.group(2).endswith("fail.py:fail"), done.stderr + done.stdout
    assert "refused to go on" in json.loads(metrics.read_text())["failure"]
    lines = [line for line in (done.stderr + done.stdout).splitlines() if line.startswith("robot ")]
    assert len(lines) == len(set(lines)), lines  # each robot's refusal said once


@pytest.mark.integration
def test_a_compiled_law_that_indexes_past_an_array_ends_the_run_and_one_that_does_not_load_is_refused(tmp_path):
    """A compiled law is bounds checked: one that reads params[3] of three (or writes past mem) raises IndexError,
    which ends the run naming it, instead of reading what lies beyond (a run that looked fine) or writing into
    the heap (a crash after the summary, exit 0). A law that does not load is refused by swarm up before
    anything starts, as by swarm sim, not by every robot after a minute's wait."""
    (tmp_path / "laws").mkdir()
    (tmp_path / "laws" / "past.py").write_text("def past(me, ref, bodies, params):\n    return params[3], 0.0\n")
    (tmp_path / "laws" / "broken.py").write_text("def broken(me, ref, bodies, params):\n    return 0.1, 0.0)\n")
    text = (EXAMPLES / "goto_slot.toml").read_text()
    for name in ("past", "broken"):
        (tmp_path / f"{name}.toml").write_text(text.replace("laws/goto_slot.py:goto_slot", f"laws/{name}.py:{name}")
                                               .replace("params = [0.5, 2.0, 1.0, 0.8, 1.0]", "params = [1, 2, 3]"))
    assert "params = [1, 2, 3]" in (tmp_path / "past.toml").read_text()
    done = subprocess.run([sys.executable, "-m", "swarm.cli", "sim", "--scenario", str(tmp_path / "past.toml"), *SMALL,
                           "--quiet"], capture_output=True, text=True, timeout=240)
    assert done.returncode == 1, done.stderr
    assert "the law 'laws/past.py:past' raised IndexError: index is out of bounds (an index past the end of params" \
        in done.stderr, done.stderr
    cmd, _ = up(tmp_path, "--scenario", str(tmp_path / "broken.toml"), *SMALL, "--quiet")
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert "swarm up: error: law 'laws/broken.py:broken'" in done.stderr and "SyntaxError" in done.stderr
    assert not (tmp_path / "logs").exists() or not list((tmp_path / "logs").glob("robot-*.log"))


@pytest.mark.integration
def test_a_law_that_returns_inf_ends_the_run_saying_so_not_that_it_raised(tmp_path):
    _, done = failing_law(tmp_path, 0.1)
    assert done.returncode == 1, done.stderr
    assert ("the law 'laws/fail.py:fail' gave robot 0 a command at t = 1 s (step 50) that made its pose non-finite"
            in done.stderr), done.stderr
    assert "raised" not in done.stderr and "Traceback" not in done.stderr


@pytest.mark.integration
def test_swarm_simulate_gives_swarm_sims_metrics_for_the_paper(tmp_path):
    code = ("import json, sys, swarm; run = swarm.simulate('paper-50hz', robots=5, duration=4, seed=2); "
            "json.dump(run.metrics, sys.stdout); "
            "assert run.q.shape == (run.t.shape[0], 5, 3) and run.err.shape == run.q.shape and run.cmd.shape[2] == 2")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    same_run(sim_metrics(tmp_path, "--scenario", "paper-50hz", *SMALL, "--seed", "2"), json.loads(done.stdout))


@pytest.mark.integration
def test_swarm_simulate_takes_a_thread_count_and_refuses_a_bad_one():
    """threads=2 runs the parallel loop with the same bits as threads=1; 0, 1.5 and True are refused by name."""
    import swarm

    one = swarm.simulate("paper-50hz", robots=5, duration=2, seed=1, threads=1)
    two = swarm.simulate("paper-50hz", robots=5, duration=2, seed=1, threads=2)
    assert (one.q == two.q).all() and (one.cmd == two.cmd).all()
    assert {k: v for k, v in one.metrics.items() if "wall" not in k} == \
        {k: v for k, v in two.metrics.items() if "wall" not in k}
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="threads must be an int >= 1"):
            swarm.simulate("paper-50hz", robots=5, duration=1, threads=bad)

"""Scenario files (docs/scenarios.md): strict refusals, precedence, what cannot run, advisories (the built-ins
and the generators: test_scenario_builtins.py)."""

from __future__ import annotations

import os

import numpy as np
import pytest
from numpy.testing import assert_allclose

from swarm.core import generators
from swarm.core import scenario_file as sf
from swarm.core.geometry import closest_pair
from swarm.core.scenario import ScenarioError

pytestmark = pytest.mark.unit

# The example of the scenario contract (docs/scenarios.md), as first written.
DESIGN_EXAMPLE = """
[run]
duration = 120.0      # s
dt = 0.001            # s: control period (and integration step in lock-step)
seed = 0

[control]
k1 = 0.5
k2 = 0.5
k3 = 1.0
tu = 1.0              # s, reference refresh period while frozen
vt = 0.05             # m/s, threshold of Assumption 3
threshold = "frozen"  # when Assumption 3 applies: "frozen" | "always" | "off"
governor = false      # the discrete-time safety governor (see the core issue)

[bodies]              # default radii of every robot and obstacle
r = 0.3
R = 1.2

[leader]
start = [0.0, 0.0, 0.0]                   # x, y, theta at t = 0
segments = [                              # piecewise-constant leader controls
  { duration = 10.0, v = 0.5, w = 0.0 },  # straight for 10 s at 0.5 m/s
  { duration = 16.0, v = 0.5, w = 0.0982 },  # left arc (w > 0 turns left)
]                                         # after the last segment the leader keeps its v, w

[formation]
offsets = [[0.0, 0.0], [1.5, 0.0]]        # d_i, one per robot
assignment = "random"                     # or "ordered": robot i gets offsets[i]

[robots]
poses = [[-8.0, 1.0, 0.3], [-9.0, -2.0, 1.2]]   # initial x, y, theta

[[obstacles]]
center = [-3.0, 0.0]
r = 0.3                                   # optional, defaults from [bodies]
R = 1.2                                   # optional, defaults from [bodies]
"""


def refused(path, overrides=sf.Overrides()):
    with pytest.raises(ScenarioError) as info:
        sf.load(path, overrides)
    return info.value


def check_refusal(e, where, key, *fragments):
    assert e.where == where
    assert e.key == key
    for f in fragments:
        assert f.lower() in e.reason.lower(), f"{f!r} not in {e.reason!r}"
    assert where in str(e) and e.reason in str(e) and (key in str(e))


# --------------------------------------------------------------------------- refusals

def _set(path, value):
    """An edit that sets doc[a][b]... = value (ints index lists); value DELETE removes the key."""

    def edit(doc):
        node = doc
        for k in path[:-1]:
            node = node[k]
        if value is DELETE:
            del node[path[-1]]
        else:
            node[path[-1]] = value

    return edit


DELETE = object()
NAN, INF = float("nan"), float("inf")

REFUSALS = [
    # unknown keys
    ("unknown top-level key", _set(("colour",), "red"), "colour", "unknown key"),
    ("unknown run key", _set(("run", "speed"), 1.0), "run.speed", "unknown key"),
    ("unknown control key", _set(("control", "k4"), 1.0), "control.k4", "unknown key"),
    ("unknown segment key", _set(("leader", "segments", 0, "omega"), 0.1), "leader.segments[0].omega", "unknown key"),
    ("unknown obstacle key", _set(("obstacles", 0, "radius"), 0.1), "obstacles[0].radius", "unknown key"),
    ("unknown bodies key", _set(("bodies", "rr"), 0.1), "bodies.rr", "unknown key"),
    ("unknown hex key", _set(("formation",), {"hex": {"count": 2, "spacing": 1.5, "rings": 1}}),
     "formation.hex.rings", "unknown key"),
    ("unknown random key", _set(("robots",), {"random": {"count": 2, "region": [0.0, 5.0, 0.0, 5.0], "spread": 1}}),
     "robots.random.spread", "unknown key"),
    ("unknown row key", _set(("obstacles", 0), {"row": {"start": [0.0, 5.0], "end": [5.0, 5.0], "pitch": 1.0,
                                                        "count": 3}}), "obstacles[0].row.count", "unknown key"),
    # missing required keys
    ("missing run", _set(("run",), DELETE), "run", "missing"),
    ("missing run.duration", _set(("run", "duration"), DELETE), "run.duration", "missing"),
    ("missing leader.start", _set(("leader", "start"), DELETE), "leader.start", "missing"),
    ("missing leader.segments", _set(("leader", "segments"), DELETE), "leader.segments", "missing"),
    ("missing segment v", _set(("leader", "segments", 0, "v"), DELETE), "leader.segments[0].v", "missing"),
    ("missing formation", _set(("formation",), DELETE), "formation", "missing"),
    ("missing robots", _set(("robots",), DELETE), "robots", "missing"),
    ("missing obstacle center", _set(("obstacles", 0, "center"), DELETE), "obstacles[0]", "exactly one"),
    # wrong types
    ("string for a number", _set(("run", "duration"), "20"), "run.duration", "must be a number", "string"),
    ("bool for a number", _set(("run", "dt"), True), "run.dt", "must be a number", "boolean"),
    ("bool for a gain", _set(("control", "k1"), False), "control.k1", "must be a number"),
    ("string in a vector", _set(("leader", "start", 1), "north"), "leader.start[1]", "must be a number"),
    ("string for a segment v", _set(("leader", "segments", 0, "v"), "fast"), "leader.segments[0].v", "number"),
    ("float for the seed", _set(("run", "seed"), 1.5), "run.seed", "integer"),
    ("bool for the seed", _set(("run", "seed"), True), "run.seed", "integer"),
    ("negative seed", _set(("run", "seed"), -1), "run.seed", ">= 0"),
    ("int for the governor", _set(("control", "governor"), 1), "control.governor", "true or false"),
    ("bad threshold", _set(("control", "threshold"), "sometimes"), "control.threshold", "must be one of", "sometimes"),
    ("bad assignment", _set(("formation", "assignment"), "sorted"), "formation.assignment", "must be one of"),
    ("table expected", _set(("run",), 5), "run", "must be a table"),
    ("short start", _set(("leader", "start"), [0.0, 0.0]), "leader.start", "list of 3"),
    ("start not a list", _set(("leader", "start"), "origin"), "leader.start", "list of 3"),
    ("3-vector offset", _set(("formation", "offsets", 1), [1.5, 0.0, 0.0]), "formation.offsets[1]", "list of 2"),
    ("2-vector pose", _set(("robots", "poses", 0), [1.0, 2.0]), "robots.poses[0]", "list of 3"),
    ("poses not a list", _set(("robots", "poses"), "here"), "robots.poses", "list"),
    ("obstacles as a table", _set(("obstacles",), {"center": [1.0, 1.0]}), "obstacles", "array of tables"),
    ("short obstacle center", _set(("obstacles", 0, "center"), [1.0]), "obstacles[0].center", "list of 2"),
    ("segment not a table", _set(("leader", "segments"), [1.0]), "leader.segments[0]", "must be a table"),
    ("zero row pitch", _set(("obstacles", 0), {"row": {"start": [0.0, 5.0], "end": [5.0, 5.0], "pitch": 0.0}}),
     "obstacles[0].row.pitch", "> 0"),
    ("segments not a list", _set(("leader", "segments"), {"duration": 1.0, "v": 0.5, "w": 0.0}),
     "leader.segments", "non-empty list"),
    # non-finite numbers
    ("nan duration", _set(("run", "duration"), NAN), "run.duration", "finite", "nan"),
    ("inf dt", _set(("run", "dt"), INF), "run.dt", "finite", "inf"),
    ("-inf gain", _set(("control", "k1"), -INF), "control.k1", "finite"),
    ("nan in start", _set(("leader", "start", 2), NAN), "leader.start[2]", "finite"),
    ("inf in offsets", _set(("formation", "offsets", 1, 0), INF), "formation.offsets[1][0]", "finite"),
    ("nan in poses", _set(("robots", "poses", 1, 1), NAN), "robots.poses[1][1]", "finite"),
    ("inf obstacle", _set(("obstacles", 0, "center", 0), -INF), "obstacles[0].center[0]", "finite"),
    ("nan segment w", _set(("leader", "segments", 0, "w"), NAN), "leader.segments[0].w", "finite"),
    ("nan r", _set(("bodies", "r"), NAN), "bodies.r", "finite"),
    # zero or negative durations, periods and gains
    ("zero duration", _set(("run", "duration"), 0.0), "run.duration", "> 0"),
    ("negative duration", _set(("run", "duration"), -5.0), "run.duration", "> 0"),
    ("zero dt", _set(("run", "dt"), 0.0), "run.dt", "> 0"),
    ("negative dt", _set(("run", "dt"), -0.01), "run.dt", "> 0"),
    ("zero int dt", _set(("run", "dt"), 0), "run.dt", "> 0"),
    ("zero segment duration", _set(("leader", "segments", 0, "duration"), 0.0), "leader.segments[0].duration", "> 0"),
    ("negative segment duration", _set(("leader", "segments", 0, "duration"), -1.0),
     "leader.segments[0].duration", "> 0"),
    ("zero tu", _set(("control", "tu"), 0.0), "control.tu", "> 0"),
    ("negative k2", _set(("control", "k2"), -0.5), "control.k2", "> 0"),
    ("negative vt", _set(("control", "vt"), -0.01), "control.vt", ">= 0"),
    ("zero r", _set(("bodies", "r"), 0.0), "bodies.r", "> 0"),
    # radii
    ("r equal to R", _set(("bodies", "r"), 1.2), "bodies.R", "larger"),
    ("r above R", _set(("bodies", "R"), 0.2), "bodies.R", "larger"),
    ("obstacle r above R", _set(("obstacles", 0, "r"), 1.5), "obstacles[0].R", "larger"),
    # Assumption 1 and start separations
    ("offsets exactly R apart", _set(("formation", "offsets"), [[0.0, 0.0], [1.2, 0.0]]), "formation.offsets",
     "Assumption 1", "R = 1.2"),
    ("offsets exactly R apart diagonally", _set(("formation", "offsets"), [[0.0, 0.0], [0.72, -0.96]]),
     "formation.offsets", "Assumption 1"),
    ("offsets closer than R", _set(("formation", "offsets"), [[0.0, 0.0], [0.5, 0.5]]), "formation.offsets",
     "Assumption 1"),
    ("duplicate offsets", _set(("formation", "offsets"), [[1.0, 1.0], [1.0, 1.0]]), "formation.offsets",
     "Assumption 1"),
    ("robots closer than r", _set(("robots", "poses"), [[0.0, 0.0, 0.0], [0.0, 0.2999, 1.0]]), "robots.poses",
     "closer than r"),
    ("robots on top of each other", _set(("robots", "poses"), [[5.0, 5.0, 0.0], [5.0, 5.0, 0.0]]), "robots.poses",
     "closer than r"),
    ("robot inside an obstacle", _set(("robots", "poses", 1), [-3.0, 0.25, 0.0]), "robots.poses", "obstacle"),
    ("robot on an obstacle centre", _set(("robots", "poses", 0), [-3.0, 0.0, 0.0]), "robots.poses", "obstacle"),
    # list lengths and generator choices
    ("more poses than offsets", _set(("robots", "poses"), [[-8.0, 1.0, 0.3], [-9.0, -2.0, 1.2], [-9.0, 4.0, 0.0]]),
     "robots.poses / formation.offsets", "3 robot poses but 2"),
    ("fewer poses than offsets", _set(("robots", "poses"), [[-8.0, 1.0, 0.3]]), "robots.poses / formation.offsets",
     "1 robot poses but 2"),
    ("hex count against poses", _set(("formation",), {"hex": {"count": 7, "spacing": 1.5}}),
     "robots.poses / formation.hex",
     "2 robot poses but 7"),
    ("empty segments", _set(("leader", "segments"), []), "leader.segments", "non-empty"),
    ("empty offsets", _set(("formation", "offsets"), []), "formation.offsets", "non-empty"),
    ("both offsets and hex", _set(("formation", "hex"), {"count": 2, "spacing": 1.5}), "formation", "exactly one"),
    ("neither offsets nor hex", _set(("formation", "offsets"), DELETE), "formation", "exactly one"),
    ("both poses and random", _set(("robots", "random"), {"count": 2, "region": [0.0, 5.0, 0.0, 5.0]}), "robots",
     "exactly one"),
    ("neither poses nor random", _set(("robots", "poses"), DELETE), "robots", "exactly one"),
    ("hex spacing within R", _set(("formation",), {"hex": {"count": 2, "spacing": 1.2}}), "formation.hex",
     "Assumption 1"),
    ("hex count zero", _set(("formation",), {"hex": {"count": 0, "spacing": 1.5}}), "formation.hex.count", ">= 1"),
    ("random region empty", _set(("robots",), {"random": {"count": 2, "region": [5.0, 0.0, 0.0, 5.0]}}),
     "robots.random.region", "xmin < xmax"),
    ("random region too small", _set(("robots",), {"random": {"count": 2, "region": [10.0, 10.1, 0.0, 0.1],
                                                              "min_separation": 1.0}}), "robots.random", "larger"),
    # speed limits and the arena
    ("zero v_max", _set(("control", "v_max"), 0.0), "control.v_max", "> 0"),
    ("negative w_max", _set(("control", "w_max"), -1.0), "control.w_max", "> 0"),
    ("string v_max", _set(("control", "v_max"), "fast"), "control.v_max", "must be a number"),
    ("inf w_max", _set(("control", "w_max"), INF), "control.w_max", "finite"),
    # beyond what the swarm's messages carry: it would run in swarm sim and not in swarm up
    ("v_max beyond the wire", _set(("control", "v_max"), 150.0), "control.v_max", "at most 100 in size",
     "what the swarm's messages carry"),
    ("w_max beyond the wire", _set(("control", "w_max"), 500.0), "control.w_max", "at most 100 in size"),
    ("segment v beyond the wire", _set(("leader", "segments", 0, "v"), -120.0), "leader.segments[0].v",
     "at most 100 in size"),
    ("segment w beyond the wire", _set(("leader", "segments", 0, "w"), 101.0), "leader.segments[0].w",
     "at most 100 in size"),
    ("leader heading beyond the wire", _set(("leader", "start", 2), 2e6), "leader.start[2]", "at most 1e+06 in size"),
    ("start heading beyond the wire", _set(("robots", "poses", 1, 2), -3e6), "robots.poses[1][2]",
     "at most 1e+06 rad in size"),
    ("leader heading that winds past the wire", _set(("leader",), {"start": [0.0, 0.0, 999_999.0], "segments": [
        {"duration": 10.0, "v": 0.5, "w": 1.0}]}), "leader.segments[0].w",
     "the leader's heading reaches 1e+06 rad by t = 20.01 s", "within 1e+06 rad"),
    ("unknown arena key", _set(("arena",), {"bounds": [0.0, 1.0, 0.0, 1.0], "walls": True}), "arena.walls",
     "unknown key"),
    ("arena bounds of 3", _set(("arena",), {"bounds": [0.0, 1.0, 0.0]}), "arena.bounds", "list of 4"),
    ("arena bounds reversed", _set(("arena",), {"bounds": [10.0, -10.0, -10.0, 10.0]}), "arena.bounds",
     "xmin < xmax"),
    ("arena bounds empty in y", _set(("arena",), {"bounds": [-10.0, 10.0, 3.0, 3.0]}), "arena.bounds", "ymin < ymax"),
    ("start outside the arena", _set(("arena",), {"bounds": [-8.5, 5.0, -5.0, 5.0]}), "robots.poses",
     "robot 1 starts at (-9, -2)", "outside arena.bounds"),
    # sizes a run cannot take
    ("huge start x", _set(("robots", "poses", 1, 0), 1e300), "robots.poses[1][0]", "at most 1e+06 m", "1e+300"),
    ("start y beyond 1e6", _set(("robots", "poses", 0, 1), -1.5e6), "robots.poses[0][1]", "at most 1e+06 m"),
    ("huge offset", _set(("formation", "offsets", 1, 1), 2e6), "formation.offsets[1][1]", "at most 1e+06 m"),
    ("huge obstacle centre", _set(("obstacles", 0, "center", 1), 3e6), "obstacles[0].center[1]", "at most 1e+06"),
    ("huge leader start", _set(("leader", "start", 0), -7e6), "leader.start[0]", "at most 1e+06"),
    ("huge bodies R", _set(("bodies", "R"), 2e6), "bodies.R", "at most 1e+06"),
    ("huge obstacle r", _set(("obstacles", 0, "r"), 1.5e6), "obstacles[0].r", "at most 1e+06"),
    ("huge row end", _set(("obstacles", 0), {"row": {"start": [0.0, 5.0], "end": [2e6, 5.0], "pitch": 1.0}}),
     "obstacles[0].row.end[0]", "at most 1e+06"),
    ("huge region", _set(("robots",), {"random": {"count": 2, "region": [0.0, 5e6, 0.0, 5.0]}}),
     "robots.random.region[1]", "at most 1e+06"),
    ("huge arena", _set(("arena",), {"bounds": [-2e6, 10.0, -10.0, 10.0]}), "arena.bounds[0]", "at most 1e+06"),
    ("huge min_separation", _set(("robots",), {"random": {"count": 2, "region": [0.0, 5.0, 0.0, 5.0],
                                                          "min_separation": 1e200}}),
     "robots.random.min_separation", "at most 1e+06"),
    ("too many hex slots", _set(("formation",), {"hex": {"count": 100_001, "spacing": 1.5}}), "formation.hex.count",
     "at most 100000"),
    ("too many random robots", _set(("robots",), {"random": {"count": 10**6, "region": [0.0, 5.0, 0.0, 5.0]}}),
     "robots.random.count", "at most 100000"),
    ("a row of 10^12 obstacles", _set(("obstacles", 0), {"row": {"start": [0.0, 5.0], "end": [1000.0, 5.0],
                                                                 "pitch": 1e-9}}),
     "obstacles[0].row", "larger pitch"),
    ("huge integer", _set(("run", "duration"), 10**400), "run.duration", "finite"),
]


@pytest.mark.parametrize("name, edit, key, fragments", [(c[0], c[1], c[2], c[3:]) for c in REFUSALS],
                         ids=[c[0] for c in REFUSALS])
def test_bad_scenario_file_is_refused_naming_file_key_and_reason(name, edit, key, fragments, base_doc,
                                                                 write_scenario):
    edit(base_doc)
    path = write_scenario(base_doc)
    check_refusal(refused(path), path, key, *fragments)
    # read_spec alone refuses what does not need the generators to run (nor the run's length, which flags may set)
    if not key.startswith(("robots", "formation.offsets", "formation.hex")) and "winds" not in name:
        with pytest.raises(ScenarioError):
            sf.read_spec(path)


def test_the_base_document_of_the_refusal_table_is_valid(base_doc, write_scenario):
    scn = sf.load(write_scenario(base_doc))
    assert scn.n == 2 and len(scn.obstacles) == 1


@pytest.mark.parametrize(
    "edit",
    [
        _set(("formation", "offsets"), [[0.0, 0.0], [1.2000001, 0.0]]),  # just beyond R
        _set(("robots", "poses"), [[0.0, 0.0, 0.0], [0.0, 0.3, 1.0]]),  # exactly r apart
        _set(("robots", "poses", 1), [-3.0, 0.5, 0.0]),  # outside the obstacle's r, inside its R
        _set(("control", "vt"), 0.0),
        _set(("run", "seed"), 2**40),
    ],
)
def test_values_at_the_limits_are_accepted(edit, base_doc, write_scenario):
    edit(base_doc)
    sf.load(write_scenario(base_doc))


def test_obstacle_radius_of_its_own_counts_for_the_start_check(base_doc, write_scenario):
    base_doc["obstacles"][0].update({"r": 0.6, "R": 1.5})
    base_doc["robots"]["poses"][1] = [-3.0, 0.5, 0.0]
    path = write_scenario(base_doc)
    check_refusal(refused(path), path, "robots.poses", "obstacle 0", "r = 0.6")


def test_int_is_accepted_where_a_float_is_expected(base_doc, write_scenario):
    base_doc["run"].update({"duration": 20, "dt": 1})
    base_doc["bodies"].update({"r": 1, "R": 2})
    base_doc["control"]["k1"] = 2
    base_doc["formation"]["offsets"] = [[0, 0], [3, 0]]
    base_doc["robots"]["poses"] = [[-10, 5, 0], [-10, 8, 1]]
    scn = sf.load(write_scenario(base_doc))
    assert (scn.duration, scn.dt, scn.r, scn.R, scn.control.k1) == (20.0, 1.0, 1.0, 2.0, 2.0)
    assert all(isinstance(v, float) for v in (scn.duration, scn.dt, scn.r, scn.R, scn.control.k1))
    assert scn.offsets.dtype == np.float64 and scn.poses.dtype == np.float64


def test_invalid_toml_is_refused(write_scenario):
    path = write_scenario("[run]\nduration = = 3\n")
    check_refusal(refused(path), path, "", "not valid TOML", "line 2")


def test_unreadable_file_is_refused(tmp_path):
    path = tmp_path / "latin1.toml"
    path.write_bytes(b"[run]\nduration = 1.0 # \xe9t\xe9\n")
    check_refusal(refused(str(path)), str(path), "", "not UTF-8 text (byte 23, line 2)")
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)  # exists, but no file: reading it would block
    check_refusal(refused(str(fifo)), str(fifo), "", "is not a regular file")


def test_toml_nan_and_inf_literals_are_refused(write_scenario):
    for literal in ("nan", "+inf", "-inf", "inf"):
        text = DESIGN_EXAMPLE.replace("duration = 120.0", f"duration = {literal}")
        path = write_scenario(text, f"x{literal}.toml")
        check_refusal(refused(path), path, "run.duration", "finite")


def test_missing_file_is_refused(tmp_path):
    path = str(tmp_path / "nowhere.toml")
    check_refusal(refused(path), path, "", "no such file")
    e = refused(str(tmp_path / "nowhere"))
    assert "paper" in e.reason  # names the built-ins when it may have been meant as one


def test_directory_is_not_a_scenario(tmp_path):
    check_refusal(refused(str(tmp_path)), str(tmp_path), "", "is a directory")


def test_robots_flag_with_explicit_lists_of_another_length(base_doc, write_scenario):
    path = write_scenario(base_doc)
    check_refusal(refused(path, sf.Overrides(robots=3)), path, "formation.offsets", "--robots 3", "2 offsets")
    assert sf.load(path, sf.Overrides(robots=2)).n == 2  # the same length is fine
    base_doc["formation"] = {"hex": {"count": 2, "spacing": 1.5}}
    path = write_scenario(base_doc, "hex.toml")
    check_refusal(refused(path, sf.Overrides(robots=3)), path, "robots.poses", "--robots 3", "2 poses")


@pytest.mark.parametrize(
    "overrides, key",
    [
        (sf.Overrides(robots=0), "--robots"),
        (sf.Overrides(robots=-2), "--robots"),
        (sf.Overrides(seed=-1), "--seed"),
        (sf.Overrides(duration=0.0), "--duration"),
        (sf.Overrides(duration=-3.0), "--duration"),
        (sf.Overrides(dt=0.0), "--dt"),
        (sf.Overrides(dt=NAN), "--dt"),
        (sf.Overrides(duration=INF), "--duration"),
    ],
)
def test_bad_command_line_values_are_refused(overrides, key, base_doc, write_scenario):
    path = write_scenario(base_doc)
    e = refused(path, overrides)
    assert e.where == "command line" and e.key == key
    e = refused("paper", overrides)
    assert e.where == "command line" and e.key == key


def test_unknown_builtin_is_refused():
    e = refused("papers")
    assert e.key == "" and "no such file" in e.reason and "paper-50hz" in e.reason


# --------------------------------------------------------------------------- valid files


def test_design_example_loads(write_scenario):
    path = write_scenario(DESIGN_EXAMPLE, "example.toml")
    spec = sf.read_spec(path)
    assert spec.where == path and spec.name == "example"
    scn = sf.load(path)
    assert (scn.duration, scn.dt, scn.seed, scn.r, scn.R) == (120.0, 0.001, 0, 0.3, 1.2)
    c = scn.control
    assert (c.k1, c.k2, c.k3, c.tu, c.vt, c.threshold, c.governor) == (0.5, 0.5, 1.0, 1.0, 0.05, "frozen", False)
    assert scn.leader.start == (0.0, 0.0, 0.0)
    assert [(s.duration, s.v, s.w) for s in scn.leader.segments] == [(10.0, 0.5, 0.0), (16.0, 0.5, 0.0982)]
    assert_allclose(scn.poses, [[-8.0, 1.0, 0.3], [-9.0, -2.0, 1.2]])
    # assignment = "random": the same slots, in some order
    assert sorted(map(tuple, scn.offsets)) == [(0.0, 0.0), (1.5, 0.0)]
    assert_allclose(scn.obstacles, [[-3.0, 0.0, 0.3, 1.2]])
    assert scn.steps == 120_000
    assert scn.cell_side == pytest.approx(1.5)


def test_defaults_fill_what_the_file_leaves_out(write_scenario):
    path = write_scenario("""
[run]
duration = 5
[leader]
start = [0.0, 0.0, 0.0]
segments = [{duration = 1.0, v = 0.5, w = 0.0}]
[formation]
offsets = [[0.0, 0.0]]
[robots]
poses = [[-1.0, 0.0, 0.0]]
""")
    scn = sf.load(path)
    assert (scn.dt, scn.seed, scn.r, scn.R) == (0.001, 0, 0.3, 1.2)
    c = scn.control
    assert (c.k1, c.k2, c.k3, c.tu, c.vt, c.threshold, c.governor) == (0.5, 0.5, 1.0, 1.0, 0.05, "frozen", False)
    assert len(scn.obstacles) == 0 and scn.obstacles.shape == (0, 4)


def test_file_beats_defaults_and_flags_beat_the_file(base_doc, write_scenario):
    base_doc["run"].update({"duration": 7.0, "dt": 0.02, "seed": 5})
    base_doc["control"].update({"k1": 0.7, "tu": 2.0, "vt": 0.1, "threshold": "always", "governor": True})
    base_doc["bodies"].update({"r": 0.25, "R": 1.0})
    base_doc["obstacles"] = [{"center": [-3.0, 0.0]}, {"center": [-3.0, 5.0], "r": 0.4, "R": 2.0}]
    path = write_scenario(base_doc)
    scn = sf.load(path)
    assert (scn.duration, scn.dt, scn.seed, scn.r, scn.R) == (7.0, 0.02, 5, 0.25, 1.0)
    c = scn.control
    assert (c.k1, c.tu, c.vt, c.threshold, c.governor) == (0.7, 2.0, 0.1, "always", True)
    assert_allclose(scn.obstacles, [[-3.0, 0.0, 0.25, 1.0], [-3.0, 5.0, 0.4, 2.0]])  # [bodies] defaults
    assert scn.cell_side == pytest.approx(2.3)

    scn = sf.load(path, sf.Overrides(seed=9, duration=3.0, dt=0.005, governor=False))
    assert (scn.duration, scn.dt, scn.seed, scn.control.governor) == (3.0, 0.005, 9, False)
    assert scn.control.k1 == 0.7  # untouched by the flags
    p = scn.params()
    from swarm.core import law

    assert p[law.P_DT] == 0.005 and p[law.P_GOVERNOR] == 0.0 and p[law.P_THRESHOLD] == law.THRESHOLD_ALWAYS
    assert sf.load(path, sf.Overrides(governor=True)).control.governor is True
    base_doc["control"]["governor"] = False
    assert sf.load(write_scenario(base_doc, "g.toml"), sf.Overrides(governor=True)).control.governor is True


GENERATED = """
[run]
duration = 10.0
seed = {seed}

[formation]
hex = {{count = {n}, spacing = 1.5}}
assignment = "random"

[robots]
random = {{count = {n}, region = [-10.0, 10.0, -30.0, -15.0], min_separation = 0.8}}

[leader]
start = [0.0, 0.0, 0.0]
segments = [{{duration = 1.0, v = 0.5, w = 0.0}}]

[[obstacles]]
row = {{start = [-12.0, -10.0], end = [12.0, -10.0], pitch = 1.6}}
r = 0.35

[[obstacles]]
center = [0.0, -22.0]
"""


def test_generators_in_a_file(write_scenario):
    path = write_scenario(GENERATED.format(seed=4, n=19))
    scn = sf.load(path)
    assert scn.n == 19
    assert sorted(map(tuple, np.round(scn.offsets, 12))) == sorted(map(tuple, np.round(generators.hex_patch(19, 1.5), 12)))
    assert (scn.poses[:, 0] >= -10).all() and (scn.poses[:, 0] <= 10).all()
    assert (scn.poses[:, 1] >= -30).all() and (scn.poses[:, 1] <= -15).all()
    d = np.hypot(*(scn.poses[:, None, :2] - scn.poses[None, :, :2]).transpose(2, 0, 1))
    d[np.diag_indices(19)] = np.inf
    assert d.min() >= 0.8
    row = scn.obstacles[:-1]
    assert len(row) == 16 and (row[:, 1] == -10.0).all() and (row[:, 2] == 0.35).all() and (row[:, 3] == 1.2).all()
    assert_allclose(row[[0, -1], 0], [-12.0, 12.0])
    assert_allclose(scn.obstacles[-1], [0.0, -22.0, 0.3, 1.2])
    # obstacle clearance (default R) holds for the random starts
    assert np.hypot(scn.poses[:, 0], scn.poses[:, 1] + 22.0).min() >= 1.2
    # --robots resizes a generated file
    scn = sf.load(path, sf.Overrides(robots=7))
    assert scn.n == 7 and scn.offsets.shape == (7, 2)


def test_seeds_are_reproducible(write_scenario):
    path = write_scenario(GENERATED.format(seed=4, n=19))
    a, b = sf.load(path), sf.load(path)
    assert (a.poses == b.poses).all() and (a.offsets == b.offsets).all()
    c = sf.load(path, sf.Overrides(seed=5))
    assert not np.allclose(a.poses, c.poses) and not (a.offsets == c.offsets).all()
    d = sf.load(write_scenario(GENERATED.format(seed=5, n=19), "five.toml"))
    assert (c.poses == d.poses).all() and (c.offsets == d.offsets).all()
    for name in sf.BUILTINS:
        x, y = sf.load(name, sf.Overrides(seed=3)), sf.load(name, sf.Overrides(seed=3))
        assert (x.poses == y.poses).all() and (x.offsets == y.offsets).all()
        assert not np.allclose(x.poses, sf.load(name, sf.Overrides(seed=4)).poses)


# --------------------------------------------------------------------------- what cannot run

RUN_REFUSALS = [
    # k1 times the 8 m from robot 0's start to its slot overflows: the simulator stopped with "non-finite state"
    ("gains that overflow at t = 0", _set(("control", "k1"), 1e308), "control", "robot 0", "not finite",
     "k1 = 1e+308", "lower the gains"),
    ("dt longer than the run", _set(("run", "dt"), 200.0), "run.dt", "200 s", "longer than the run",
     "run.duration = 20 s"),
    ("more than 1e8 steps", _set(("run", "duration"), 1.5e6), "run.duration / run.dt", "1.5e+08 steps",
     "at most 1e+08"),
]


@pytest.mark.parametrize("name, edit, key, fragments", [(c[0], c[1], c[2], c[3:]) for c in RUN_REFUSALS],
                         ids=[c[0] for c in RUN_REFUSALS])
def test_a_scenario_that_cannot_run_is_refused_at_load(name, edit, key, fragments, base_doc, write_scenario):
    edit(base_doc)
    path = write_scenario(base_doc)
    check_refusal(refused(path), path, key, *fragments)


def test_the_law_check_names_the_first_robot_whose_command_overflows(base_doc, write_scenario):
    base_doc["control"]["k1"] = 1e307
    base_doc["robots"]["poses"] = [[-1.0, 0.0, 0.0], [-30.0, 1.5, 0.0]]  # 1 m and 31.5 m from their slots
    path = write_scenario(base_doc)
    check_refusal(refused(path), path, "control", "robot 1", "31.54 m from its slot",
                    "1 of the 2 robots")
    base_doc["robots"]["poses"][1] = [-15.0, 1.5, 0.0]  # 16.5 m: 1.65e308 m/s, the largest float is 1.8e308
    sf.load(write_scenario(base_doc, "fine.toml"))


def test_dt_and_duration_from_flags_are_named_as_flags(base_doc, write_scenario):
    path = write_scenario(base_doc)
    check_refusal(refused(path, sf.Overrides(dt=30.0)), path, "--dt", "longer than the run", "run.duration = 20 s")
    e = refused(path, sf.Overrides(dt=30.0, duration=5.0))
    assert (e.where, e.key) == ("command line", "--dt") and "--duration = 5 s" in e.reason
    check_refusal(refused(path, sf.Overrides(dt=1e-9)), path, "run.duration / --dt", "2e+10 steps")
    e = refused("paper", sf.Overrides(robots=100_001))
    assert (e.where, e.key) == ("command line", "--robots") and "at most 100000" in e.reason
    # the limits themselves are fine: dt = duration is one step, 1e8 steps is the most
    assert sf.load(path, sf.Overrides(dt=20.0)).steps == 1
    assert sf.load(path, sf.Overrides(duration=1e6, dt=0.01)).steps == 10**8


def test_first_commands_are_the_simulators_first_step(base_doc, write_scenario):
    """The law check evaluates exactly what the compiled simulator's first step computes."""
    from swarm.core.sim import Simulation

    # robots near each other (within the cell side) and near the obstacle, frozen or governed
    base_doc["formation"]["offsets"] = [[0.0, 0.0], [1.5, 0.0], [0.0, 1.5], [1.5, 1.5]]
    base_doc["robots"]["poses"] = [[-3.0, 1.0, 0.3], [-2.0, 1.5, 2.0], [-8.0, 1.0, -1.0], [-7.2, 1.3, 0.0]]
    for governor in (False, True):
        base_doc["control"]["governor"] = governor
        cases = [sf.load(write_scenario(base_doc, f"near{governor}.toml"))]
        cases += [sf.load(name, sf.Overrides(robots=n, seed=2)) for name, n in (("paper-50hz", 37), ("paper", 61))]
        near = cases[0]
        assert closest_pair(near.poses[:, :2], near.cell_side) is not None
        assert np.hypot(*(near.poses[0, :2] - near.obstacles[0, :2])) < near.cell_side
        for scn in cases:
            sim = Simulation(scn)
            sim.advance(1)
            assert (sf.first_commands(scn) == sim.cmd).all()


# --------------------------------------------------------------------------- speed limits and the arena


def test_speed_limits_are_carried_and_written_back(base_doc, write_scenario):
    base_doc["control"].update({"v_max": 0.8, "w_max": 2})
    scn = sf.load(write_scenario(base_doc))
    assert (scn.control.v_max, scn.control.w_max) == (0.8, 2.0) and isinstance(scn.control.w_max, float)
    text = sf.to_toml(scn)
    assert "v_max = 0.8" in text and "w_max = 2.0" in text
    again = sf.load(write_scenario(text, "again.toml"))
    assert again.control == scn.control
    del base_doc["control"]["v_max"], base_doc["control"]["w_max"]
    plain = sf.load(write_scenario(base_doc, "plain.toml"))
    assert plain.control.v_max is None and plain.control.w_max is None and "v_max" not in sf.to_toml(plain)


def test_speed_limits_fill_the_laws_slots_and_each_robots_configuration(base_doc, write_scenario):
    from swarm.core import law
    from swarm.core.scenario import Control

    p = Control(v_max=0.7, w_max=1.5).vector(0.02, 1.5, 1.2)
    assert p.shape == (law.P_SIZE,) and (p[law.P_V_MAX], p[law.P_W_MAX]) == (0.7, 1.5)
    p = Control().vector(0.02, 1.5, 1.2)
    assert (p[law.P_V_MAX], p[law.P_W_MAX]) == (0.0, 0.0) and p[law.P_K1] == 0.5  # 0: no limit
    with pytest.raises(ValueError, match="v_max"):
        Control(v_max=0.0)
    base_doc["control"]["v_max"] = 0.8
    scn = sf.load(write_scenario(base_doc))
    assert (scn.robot_config(1).v_max, scn.robot_config(1).w_max) == (0.8, 0.0)
    assert (scn.params()[law.P_V_MAX], scn.params()[law.P_W_MAX]) == (0.8, 0.0)


def test_arena_bounds_are_carried_and_written_back(base_doc, write_scenario):
    base_doc["arena"] = {"bounds": [-20, 20.0, -10.0, 10.0]}
    scn = sf.load(write_scenario(base_doc))
    assert scn.bounds == (-20.0, 20.0, -10.0, 10.0)
    assert "[arena]\nbounds = [-20.0, 20.0, -10.0, 10.0]" in sf.to_toml(scn)
    assert sf.load(write_scenario(sf.to_toml(scn), "again.toml")).bounds == scn.bounds
    del base_doc["arena"]
    assert sf.load(write_scenario(base_doc, "open.toml")).bounds is None
    base_doc["arena"] = {}  # arena.bounds is optional: an [arena] table without it is no arena
    assert sf.load(write_scenario(base_doc, "empty.toml")).bounds is None
    del base_doc["arena"]
    # a start on the border is inside
    base_doc["arena"] = {"bounds": [-9.0, 0.0, -2.0, 1.0]}
    sf.load(write_scenario(base_doc, "border.toml"))


def test_random_starts_outside_the_arena_are_refused(write_scenario):
    text = GENERATED.format(seed=4, n=19) + "\n[arena]\nbounds = [-10.0, 10.0, -22.0, 5.0]\n"
    path = write_scenario(text)
    e = refused(path)
    assert e.key == "robots.random" and "outside arena.bounds [-10, 10, -22, 5]" in e.reason


# --------------------------------------------------------------------------- advisories


def test_odd_but_legal_choices_are_warned_about(base_doc, write_scenario):
    assert sf.advisories(sf.load(write_scenario(base_doc))) == []
    base_doc["control"].update({"v_max": 0.3, "w_max": 0.05, "tu": 30.0})
    base_doc["leader"]["segments"].append({"duration": 5.0, "v": 0.2, "w": 0.1})
    base_doc["arena"] = {"bounds": [-12.0, 4.0, -5.0, 5.0]}
    notes = sf.advisories(sf.load(write_scenario(base_doc, "odd.toml")))
    text = "\n".join(notes)
    assert "leader.segments[0] moves the formation's slots at up to 0.5 m/s, faster than control.v_max = 0.3" in text
    assert "leader.segments[1] turns at 0.1 rad/s, faster than control.w_max = 0.05" in text
    assert "run.duration = 20 s is shorter than control.tu = 30 s" in text
    assert "leave arena.bounds" in text and "t = " in text
    assert len(notes) == 4


def test_a_step_longer_than_the_wait_rule_covers_is_warned_about(base_doc, write_scenario):
    base_doc["run"]["dt"] = 0.25  # 0.5 m/s: 0.125 m a step, more than (1.5 - 1.2) / 3 = 0.1 m
    notes = sf.advisories(sf.load(write_scenario(base_doc)))
    assert any("0.125 m a step" in n and "(cell side - reach) / 3 = 0.1 m" in n for n in notes), notes
    base_doc["run"]["dt"] = 0.2  # 0.1 m: at the limit, fine
    assert sf.advisories(sf.load(write_scenario(base_doc, "ok.toml"))) == []


def test_a_leader_that_travels_beyond_1e6_m_is_warned_about(base_doc, write_scenario):
    base_doc["run"].update({"duration": 1e5, "dt": 1.0})
    base_doc["leader"]["segments"][0]["v"] = 20.0  # 2e6 m in the run
    notes = sf.advisories(sf.load(write_scenario(base_doc)))
    assert any("leader may travel 2e+06 m" in n for n in notes), notes


# --------------------------------------------------------------------------- progress


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_the_progress_reporter_stays_silent_for_a_second_then_reports(capsys):
    clock = FakeClock()
    rep = sf.StderrProgress(clock=clock)
    rep("checking the start separations", 0, 10)
    clock.t += 0.9
    rep("checking the start separations", 5, 10)
    rep.finish()
    assert capsys.readouterr().err == ""  # a quick load prints nothing
    clock.t += 0.2
    rep("evaluating the law at t = 0", 0, 10)
    rep("evaluating the law at t = 0", 4, 10)  # the same stage within a second: not again
    clock.t += 1.0
    rep("evaluating the law at t = 0", 8, 10)
    rep("evaluating the law at t = 0", 10, 10)
    rep.finish()
    assert capsys.readouterr().err.splitlines() == [
        "scenario: evaluating the law at t = 0 ...",
        "scenario: evaluating the law at t = 0: 8 of 10",
        "scenario: ready after 2.1 s",
    ]


def test_load_reports_its_stages_to_a_progress_callable():
    seen = []
    sf.load("paper-50hz", sf.Overrides(robots=5000), progress=lambda stage, done, total: seen.append(stage))
    for stage in ("drawing random starts", "checking the formation's slots", "checking the start separations",
                  "evaluating the law at t = 0"):
        assert stage in seen, seen


# --------------------------------------------------------------------------- large files


def test_a_file_of_too_many_poses_is_refused_from_its_text(tmp_path, base_doc):
    from tests.conftest import toml_text

    poses = "\n".join(f"  [{i % 1000 * 2.0}, {i // 1000 * 2.0}, 0.0]," for i in range(100_001))
    text = toml_text(base_doc).replace('poses = [[-8.0, 1.0, 0.3], [-9.0, -2.0, 1.2]]', f"poses = [\n{poses}\n]")
    assert "poses = [\n" in text
    path = tmp_path / "many.toml"
    path.write_text(text)
    e = refused(str(path))
    assert e.key == "robots.poses" and "lists 100001 entries" in e.reason


def test_the_prescan_skips_strings_and_comments(tmp_path, base_doc):
    """Brackets in comments and strings are not entries; a large valid file loads."""
    from tests.conftest import toml_text

    n = 30_000
    poses = "\n".join(f"  [{i % 200 * 2.0}, {-10.0 - i // 200 * 2.0}, 0.0],  # [[ not [an] entry ]]"
                      for i in range(n))
    offsets = "\n".join(f"  [{i % 200 * 1.5}, {i // 200 * 1.5}]," for i in range(n))
    base_doc["formation"]["offsets"] = [[0.0, 0.0]]
    base_doc["robots"]["poses"] = [[0.0, 0.0, 0.0]]
    text = toml_text(base_doc).replace("offsets = [[0.0, 0.0]]", f"offsets = [\n{offsets}\n]")
    text = text.replace("poses = [[0.0, 0.0, 0.0]]", f"poses = [\n{poses}\n]")
    text = f'# "[" {"[" * 200_000}\n' + text
    path = tmp_path / "large.toml"
    path.write_text(text)
    assert path.stat().st_size > sf.PRESCAN_BYTES
    scn = sf.load(str(path), progress=sf.silent)
    assert scn.n == n


def test_the_scenario_limits_are_the_wires():
    """A scenario the swarm's messages cannot carry is refused at load, not found out by a robot that never
    starts (a heading, a speed or an obstacle count that swarm sim ran and swarm up did not)."""
    from swarm.proto import protocol

    assert sf.MAX_ANGLE == protocol.MAX_ANGLE and sf.MAX_SPEED == protocol.MAX_SPEED
    assert sf.MAX_TURN == protocol.MAX_TURN and sf.MAX_COORD == protocol.MAX_COORD
    assert sf.MAX_OBSTACLES == sf.MAX_ROBOTS == protocol.MAX_ROBOTS  # the obstacles message's list limit

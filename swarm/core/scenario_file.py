"""Scenario files (DESIGN.md section 6, TOML) and the built-in scenarios.

    load("paper")                      -> Scenario   (a built-in name)
    load("my.toml", Overrides(seed=3)) -> Scenario   (a file; flags beat the file)

A file is read into a `Spec` (every key checked: unknown, missing, wrong type,
non-finite, out of range), the command-line overrides are applied, generators are run
with the run's seed, and the result is checked as a whole (Assumption 1, start
separations, list lengths). Every refusal is a ScenarioError naming the file, the key
and the reason. Built-in scenarios are written as the same dictionaries a TOML file
parses into, so they pass through the very same checks.

Randomness: one numpy Generator seeded with run.seed draws, in this order, the random
start poses (robots.random) and then the random assignment of slots to robots.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarm.core import generators
from swarm.core.scenario import THRESHOLDS, Control, Leader, Scenario, ScenarioError, Segment

BUILTINS = ("paper", "paper-50hz")


@dataclass(frozen=True)
class Overrides:
    """Command-line flags; None means "not given" (the file or the default decides)."""

    robots: int | None = None
    seed: int | None = None
    duration: float | None = None
    dt: float | None = None
    governor: bool | None = None


@dataclass(frozen=True)
class Spec:
    """A checked scenario file whose generators have not run yet."""

    where: str
    name: str
    duration: float
    dt: float
    seed: int
    control: Control
    r: float
    R: float
    leader: Leader
    offsets: np.ndarray | None  # explicit list, or None with `hex`
    hex: tuple[int, float] | None  # (count, spacing)
    assignment: str
    poses: np.ndarray | None  # explicit list, or None with `random`
    random: dict[str, Any] | None  # count, region, min_separation, obstacle_clearance
    obstacles: np.ndarray  # (M, 4), rows already expanded
    builtin: str | None = None


# --------------------------------------------------------------------------- reading


class _Reader:
    """Typed access to a parsed TOML document with errors that name file and key."""

    def __init__(self, where: str):
        self.where = where

    def fail(self, key: str, reason: str) -> ScenarioError:
        return ScenarioError(self.where, key, reason)

    def table(self, value: Any, key: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> dict:
        if not isinstance(value, dict):
            raise self.fail(key, f"must be a table, got {_kind(value)}")
        for k in value:
            if k not in allowed:
                raise self.fail(_join(key, k), f"unknown key (allowed here: {', '.join(allowed)})")
        for k in required:
            if k not in value:
                raise self.fail(_join(key, k), "missing required key")
        return value

    def number(self, value: Any, key: str, *, gt: float | None = None, ge: float | None = None) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"must be a number, got {_kind(value)}")
        x = float(value)
        if not math.isfinite(x):
            raise self.fail(key, f"must be finite, got {value}")
        if gt is not None and not x > gt:
            raise self.fail(key, f"must be > {gt:g}, got {value}")
        if ge is not None and not x >= ge:
            raise self.fail(key, f"must be >= {ge:g}, got {value}")
        return x

    def integer(self, value: Any, key: str, *, ge: int = 0) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(key, f"must be an integer, got {_kind(value)}")
        if value < ge:
            raise self.fail(key, f"must be >= {ge}, got {value}")
        return value

    def boolean(self, value: Any, key: str) -> bool:
        if not isinstance(value, bool):
            raise self.fail(key, f"must be true or false, got {_kind(value)}")
        return value

    def choice(self, value: Any, key: str, options: tuple[str, ...]) -> str:
        if not isinstance(value, str) or value not in options:
            raise self.fail(key, f"must be one of {', '.join(repr(o) for o in options)}, got {value!r}")
        return value

    def vector(self, value: Any, key: str, length: int, what: str) -> list[float]:
        if not isinstance(value, list) or len(value) != length:
            raise self.fail(key, f"must be a list of {length} numbers [{what}], got {_show(value)}")
        return [self.number(v, f"{key}[{i}]") for i, v in enumerate(value)]

    def vectors(self, value: Any, key: str, length: int, what: str) -> np.ndarray:
        if not isinstance(value, list) or not value:
            raise self.fail(key, f"must be a non-empty list of [{what}], got {_show(value)}")
        return np.array([self.vector(v, f"{key}[{i}]", length, what) for i, v in enumerate(value)], float)


def _kind(value: Any) -> str:
    names = {bool: "a boolean", int: "an integer", float: "a number", str: "a string", list: "a list", dict: "a table"}
    return names.get(type(value), type(value).__name__)


def _show(value: Any) -> str:
    s = repr(value)
    return s if len(s) <= 60 else s[:57] + "..."


def _join(key: str, sub: str) -> str:
    return f"{key}.{sub}" if key else sub


def parse(doc: dict, where: str, name: str, builtin: str | None = None) -> Spec:
    """Check a parsed TOML document (DESIGN.md section 6) and return its Spec."""
    rd = _Reader(where)
    rd.table(doc, "", ("run", "control", "bodies", "leader", "formation", "robots", "obstacles"),
             ("run", "leader", "formation", "robots"))

    run = rd.table(doc["run"], "run", ("duration", "dt", "seed"), ("duration",))
    duration = rd.number(run["duration"], "run.duration", gt=0)
    dt = rd.number(run.get("dt", 0.001), "run.dt", gt=0)
    seed = rd.integer(run.get("seed", 0), "run.seed")

    ctl = rd.table(doc.get("control", {}), "control", ("k1", "k2", "k3", "tu", "vt", "threshold", "governor"))
    defaults = Control()
    control = Control(
        k1=rd.number(ctl.get("k1", defaults.k1), "control.k1", gt=0),
        k2=rd.number(ctl.get("k2", defaults.k2), "control.k2", gt=0),
        k3=rd.number(ctl.get("k3", defaults.k3), "control.k3", gt=0),
        tu=rd.number(ctl.get("tu", defaults.tu), "control.tu", gt=0),
        vt=rd.number(ctl.get("vt", defaults.vt), "control.vt", ge=0),
        threshold=rd.choice(ctl.get("threshold", defaults.threshold), "control.threshold", tuple(THRESHOLDS)),
        governor=rd.boolean(ctl.get("governor", defaults.governor), "control.governor"),
    )

    bodies = rd.table(doc.get("bodies", {}), "bodies", ("r", "R"))
    r = rd.number(bodies.get("r", 0.3), "bodies.r", gt=0)
    R = rd.number(bodies.get("R", 1.2), "bodies.R", gt=0)
    if not r < R:
        raise rd.fail("bodies.R", f"must be larger than bodies.r = {r:g}, got {R:g}")

    ld = rd.table(doc["leader"], "leader", ("start", "segments"), ("start", "segments"))
    start = rd.vector(ld["start"], "leader.start", 3, "x, y, theta")
    if not isinstance(ld["segments"], list) or not ld["segments"]:
        raise rd.fail("leader.segments", f"must be a non-empty list of {{duration, v, w}}, got {_show(ld['segments'])}")
    segments = []
    for i, seg in enumerate(ld["segments"]):
        key = f"leader.segments[{i}]"
        rd.table(seg, key, ("duration", "v", "w"), ("duration", "v", "w"))
        segments.append(Segment(rd.number(seg["duration"], f"{key}.duration", gt=0),
                                rd.number(seg["v"], f"{key}.v"), rd.number(seg["w"], f"{key}.w")))
    leader = Leader(tuple(start), tuple(segments))

    fm = rd.table(doc["formation"], "formation", ("offsets", "hex", "assignment"))
    offsets = hex_ = None
    if ("offsets" in fm) == ("hex" in fm):
        raise rd.fail("formation", "give exactly one of 'offsets' (a list of [dx, dy]) or 'hex' (a generator)")
    if "offsets" in fm:
        offsets = rd.vectors(fm["offsets"], "formation.offsets", 2, "dx, dy")
    else:
        hx = rd.table(fm["hex"], "formation.hex", ("count", "spacing"), ("count", "spacing"))
        hex_ = (rd.integer(hx["count"], "formation.hex.count", ge=1),
                rd.number(hx["spacing"], "formation.hex.spacing", gt=0))
    assignment = rd.choice(fm.get("assignment", "ordered"), "formation.assignment", ("ordered", "random"))

    rb = rd.table(doc["robots"], "robots", ("poses", "random"))
    poses = random = None
    if ("poses" in rb) == ("random" in rb):
        raise rd.fail("robots", "give exactly one of 'poses' (a list of [x, y, theta]) or 'random' (a generator)")
    if "poses" in rb:
        poses = rd.vectors(rb["poses"], "robots.poses", 3, "x, y, theta")
    else:
        key = "robots.random"
        rnd = rd.table(rb["random"], key, ("count", "region", "min_separation", "obstacle_clearance"),
                       ("count", "region"))
        region = rd.vector(rnd["region"], f"{key}.region", 4, "xmin, xmax, ymin, ymax")
        if not (region[0] < region[1] and region[2] < region[3]):
            raise rd.fail(f"{key}.region", f"must have xmin < xmax and ymin < ymax, got {region}")
        random = {
            "count": rd.integer(rnd["count"], f"{key}.count", ge=1),
            "region": tuple(region),
            "min_separation": rd.number(rnd.get("min_separation", 2 * r), f"{key}.min_separation", ge=0),
            "obstacle_clearance": rd.number(rnd.get("obstacle_clearance", R), f"{key}.obstacle_clearance", ge=0),
        }

    obstacles = _parse_obstacles(rd, doc.get("obstacles", []), r, R)
    return Spec(where, name, duration, dt, seed, control, r, R, leader, offsets, hex_, assignment,
                poses, random, obstacles, builtin)


def _parse_obstacles(rd: _Reader, value: Any, r: float, R: float) -> np.ndarray:
    if not isinstance(value, list):
        raise rd.fail("obstacles", f"must be an array of tables ([[obstacles]]), got {_kind(value)}")
    rows: list[tuple[float, float, float, float]] = []
    for i, ob in enumerate(value):
        key = f"obstacles[{i}]"
        rd.table(ob, key, ("center", "row", "r", "R"))
        orr = rd.number(ob.get("r", r), f"{key}.r", gt=0)
        oR = rd.number(ob.get("R", R), f"{key}.R", gt=0)
        if not orr < oR:
            raise rd.fail(f"{key}.R", f"must be larger than r = {orr:g}, got {oR:g}")
        if ("center" in ob) == ("row" in ob):
            raise rd.fail(key, "give exactly one of 'center' = [x, y] or 'row' = {start, end, pitch}")
        if "center" in ob:
            x, y = rd.vector(ob["center"], f"{key}.center", 2, "x, y")
            rows.append((x, y, orr, oR))
        else:
            row = rd.table(ob["row"], f"{key}.row", ("start", "end", "pitch"), ("start", "end", "pitch"))
            a = rd.vector(row["start"], f"{key}.row.start", 2, "x, y")
            b = rd.vector(row["end"], f"{key}.row.end", 2, "x, y")
            pitch = rd.number(row["pitch"], f"{key}.row.pitch", gt=0)
            rows.extend((float(x), float(y), orr, oR) for x, y in generators.obstacle_row(a, b, pitch))
    return np.array(rows, float).reshape(-1, 4)


# --------------------------------------------------------------------------- resolving


def resolve(spec: Spec, ov: Overrides = Overrides()) -> Scenario:
    """Apply the overrides, run the generators and check the scenario as a whole."""
    rd = _Reader(spec.where)
    if ov.robots is not None and spec.builtin is not None:
        spec = parse(builtin_document(spec.builtin, ov.robots), spec.where, spec.name, spec.builtin)
    seed = spec.seed if ov.seed is None else ov.seed
    duration = spec.duration if ov.duration is None else ov.duration
    dt = spec.dt if ov.dt is None else ov.dt
    for flag, value in (("--seed", ov.seed), ("--duration", ov.duration), ("--dt", ov.dt), ("--robots", ov.robots)):
        if value is not None and not (math.isfinite(value) and value > (-1 if flag == "--seed" else 0)):
            raise ScenarioError("command line", flag, f"must be {'>= 0' if flag == '--seed' else '> 0'}, got {value}")
    control = spec.control
    if ov.governor is not None:
        control = Control(**{**control.__dict__, "governor": ov.governor})
    rng = np.random.default_rng(seed)

    offsets = spec.offsets
    if spec.hex is not None:
        count = spec.hex[0] if ov.robots is None else ov.robots
        offsets = generators.hex_patch(count, spec.hex[1])
    elif ov.robots is not None and len(offsets) != ov.robots:
        raise rd.fail("formation.offsets", f"lists {len(offsets)} offsets explicitly; --robots {ov.robots} only "
                      "resizes scenarios made by generators (formation.hex, robots.random)")

    poses = spec.poses
    if spec.random is not None:
        g = spec.random
        count = g["count"] if ov.robots is None else ov.robots
        try:
            poses = generators.random_poses(rng, count, g["region"], g["min_separation"], spec.obstacles,
                                            g["obstacle_clearance"])
        except generators.GeneratorError as e:
            raise rd.fail("robots.random", str(e)) from None
    elif ov.robots is not None and len(poses) != ov.robots:
        raise rd.fail("robots.poses", f"lists {len(poses)} poses explicitly; --robots {ov.robots} only "
                      "resizes scenarios made by generators (formation.hex, robots.random)")

    if len(poses) != len(offsets):
        key = ("robots.random" if spec.random is not None else "robots.poses") + " / " + \
            ("formation.hex" if spec.hex is not None else "formation.offsets")
        raise rd.fail(key, f"{len(poses)} robot poses but {len(offsets)} formation offsets: "
                      "give one offset per robot")
    if spec.assignment == "random":
        offsets = offsets[rng.permutation(len(offsets))]

    scn = Scenario(spec.name, duration, dt, seed, control, spec.r, spec.R, spec.leader,
                   np.ascontiguousarray(offsets, float), np.ascontiguousarray(poses, float),
                   np.ascontiguousarray(spec.obstacles, float).reshape(-1, 4))
    check(scn, spec.where, offsets_key="formation.hex" if spec.hex else "formation.offsets",
          poses_key="robots.random" if spec.random else "robots.poses")
    return scn


def check(scn: Scenario, where: str, offsets_key: str = "formation.offsets", poses_key: str = "robots.poses") -> None:
    """Assumption 1 and the start separations; raises ScenarioError."""
    off = scn.offsets
    i, j, d = _closest_pair(off)
    if d is not None and d <= scn.R:
        raise ScenarioError(where, offsets_key, f"slots of robots {i} and {j} are {d:.4g} m apart; "
                            f"formation offsets must be more than R = {scn.R:g} m apart (Assumption 1)")
    i, j, d = _closest_pair(scn.poses[:, :2])
    if d is not None and d < scn.r:
        raise ScenarioError(where, poses_key, f"robots {i} and {j} start {d:.4g} m apart, closer than r = {scn.r:g} m")
    if len(scn.obstacles):
        dist = _start_obstacle_distances(scn)
        bad = dist < scn.obstacles[None, :, 2]
        if bad.any():
            i, o = map(int, np.argwhere(bad)[0])
            raise ScenarioError(where, poses_key, f"robot {i} starts {dist[i, o]:.4g} m from obstacle {o} "
                                f"at ({scn.obstacles[o, 0]:g}, {scn.obstacles[o, 1]:g}), closer than its "
                                f"r = {scn.obstacles[o, 2]:g} m")


STEEP_START = 0.02  # share of (R - r): a start this close above r is allowed but warned about


def advisories(scn: Scenario) -> list[str]:
    """Valid but risky choices, to warn about (the contract accepts them)."""
    out = []
    i, j, d = _closest_pair(scn.poses[:, :2])
    hint = "" if scn.control.governor else " (the governor, --governor, limits that)"
    if d is not None and d < scn.r + STEEP_START * (scn.R - scn.r):
        out.append(f"robots {i} and {j} start {d:.4g} m apart, just outside r = {scn.r:g} m: the repulsion there is "
                   f"so steep that one step can throw them far apart{hint}")
    if len(scn.obstacles) and scn.n:
        dist = _start_obstacle_distances(scn)
        ro, Ro = scn.obstacles[None, :, 2], scn.obstacles[None, :, 3]
        steep = dist < ro + STEEP_START * (Ro - ro)
        if steep.any():
            i, o = map(int, np.argwhere(steep)[0])
            out.append(f"robot {i} starts {dist[i, o]:.4g} m from obstacle {o}, just outside its r = "
                       f"{scn.obstacles[o, 2]:g} m: the repulsion there is so steep that one step can throw the "
                       f"robot far away{hint}")
    return out


def _start_obstacle_distances(scn: Scenario) -> np.ndarray:
    """(N, M) distances from each robot's start to each obstacle's centre [m]."""
    diff = scn.poses[:, None, :2] - scn.obstacles[None, :, :2]
    return np.sqrt(np.sum(diff * diff, axis=2))


def _closest_pair(points: np.ndarray) -> tuple[int, int, float | None]:
    """The closest pair of rows of (K, 2) points (grid-free but chunked: fine to ~10^4)."""
    n = len(points)
    if n < 2:
        return -1, -1, None
    best = (math.inf, -1, -1)
    for a in range(0, n, 512):
        block = points[a:a + 512]
        d2 = np.sum((block[:, None, :] - points[None, :, :]) ** 2, axis=2)
        rows = np.arange(len(block))
        d2[rows, a + rows] = np.inf
        k = int(np.argmin(d2))
        bi, bj = divmod(k, n)
        if d2[bi, bj] < best[0]:
            best = (float(d2[bi, bj]), a + bi, bj)
    i, j = sorted((best[1], best[2]))
    return i, j, math.sqrt(best[0])


# --------------------------------------------------------------------------- built-ins


def builtin_document(name: str, robots: int | None = None) -> dict:
    """The built-in scenario `name` as the dictionary its TOML file would parse into.

    `paper` models the paper's Section 7 experiment: 37 robots, a 1.5 m hexagonal patch,
    a barrier of obstacles 2.6 m below the lowest slot, random starts below the barrier.
    `robots` scales it: the patch grows ring by ring, the start rectangle keeps 9 m^2 per
    robot (aspect 2.8:1, centred on x = 5 m, top edge 1.5 m below the barrier), and the
    barrier spans the rectangle plus 4.75 m on each side (centred on x = 4.7 m).
    `paper-50hz` is the same geometry at dt = 0.02 s with the safety governor on.
    """
    if name not in BUILTINS:
        raise ScenarioError(name, "", f"no such built-in scenario (built-ins: {', '.join(BUILTINS)}; "
                            "or give a path to a .toml file)")
    n = 37 if robots is None else robots
    if n < 1:
        raise ScenarioError("command line", "--robots", f"must be >= 1, got {n}")
    width = math.sqrt(9.0 * n * 2.8)
    height = 9.0 * n / width
    lowest = float(generators.hex_patch(n, 1.5)[:, 1].min())
    barrier_y = lowest - 2.6
    intervals = max(1, round((width + 9.5) / 1.6))
    top = barrier_y - 1.5
    turn = math.pi / 32.0
    return {
        "run": {"duration": 120.0, "dt": 0.001 if name == "paper" else 0.02, "seed": 0},
        "control": {"k1": 0.5, "k2": 0.5, "k3": 1.0, "tu": 1.0, "vt": 0.05, "threshold": "frozen",
                    "governor": name == "paper-50hz"},
        "bodies": {"r": 0.3, "R": 1.2},
        "leader": {"start": [0.0, 0.0, 0.0], "segments": [
            {"duration": 10.0, "v": 0.5, "w": 0.0},
            {"duration": 16.0, "v": 0.5, "w": turn},
            {"duration": 8.0, "v": 0.5, "w": 0.0},
            {"duration": 16.0, "v": 0.5, "w": -turn},
            {"duration": 70.0, "v": 0.5, "w": 0.0},
        ]},
        "formation": {"hex": {"count": n, "spacing": 1.5}, "assignment": "random"},
        "robots": {"random": {"count": n, "region": [5.0 - width / 2, 5.0 + width / 2, top - height, top],
                              "min_separation": 0.8, "obstacle_clearance": 1.2}},
        "obstacles": [{"row": {"start": [4.7 - 0.8 * intervals, barrier_y], "end": [4.7 + 0.8 * intervals, barrier_y],
                               "pitch": 1.6}}],
    }


def read_spec(source: str) -> Spec:
    """A built-in name or a path to a TOML file, checked."""
    if source in BUILTINS:
        return parse(builtin_document(source), f"built-in scenario '{source}'", source, builtin=source)
    path = Path(source)
    if not path.is_file():
        hint = "" if source.endswith(".toml") else f" (built-ins: {', '.join(BUILTINS)})"
        raise ScenarioError(source, "", f"no such file{hint}")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(source, "", f"not valid TOML: {e}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ScenarioError(source, "", f"cannot read: {e}") from None
    return parse(doc, source, path.stem)


def load(source: str, overrides: Overrides = Overrides()) -> Scenario:
    """Read, check and resolve a scenario (a built-in name or a TOML path)."""
    return resolve(read_spec(source), overrides)


def to_toml(scn: Scenario) -> str:
    """The resolved scenario as a TOML file with explicit lists (loads back to the same numbers)."""

    def num(x: float) -> str:
        return repr(float(x))

    def vec(v) -> str:
        return "[" + ", ".join(num(x) for x in v) + "]"

    c = scn.control
    lines = [
        f"# scenario '{scn.name}': {scn.n} robots, {len(scn.obstacles)} obstacles (written by swarm scenario show)",
        "[run]", f"duration = {num(scn.duration)}", f"dt = {num(scn.dt)}", f"seed = {scn.seed}", "",
        "[control]", f"k1 = {num(c.k1)}", f"k2 = {num(c.k2)}", f"k3 = {num(c.k3)}", f"tu = {num(c.tu)}",
        f"vt = {num(c.vt)}", f'threshold = "{c.threshold}"', f"governor = {'true' if c.governor else 'false'}", "",
        "[bodies]", f"r = {num(scn.r)}", f"R = {num(scn.R)}", "",
        "[leader]", f"start = {vec(scn.leader.start)}", "segments = [",
        *[f"  {{ duration = {num(s.duration)}, v = {num(s.v)}, w = {num(s.w)} }}," for s in scn.leader.segments],
        "]", "",
        "[formation]", 'assignment = "ordered"', "offsets = [", *[f"  {vec(o)}," for o in scn.offsets], "]", "",
        "[robots]", "poses = [", *[f"  {vec(q)}," for q in scn.poses], "]",
    ]
    for x, y, r, R in scn.obstacles:
        lines += ["", "[[obstacles]]", f"center = {vec((x, y))}", f"r = {num(r)}", f"R = {num(R)}"]
    return "\n".join(lines) + "\n"

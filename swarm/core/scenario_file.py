"""Scenario files (docs/scenarios.md, TOML) and the built-in scenarios.

    load("paper")                      -> Scenario   (a built-in name)
    load("my.toml", Overrides(seed=3)) -> Scenario   (a file; flags beat the file)

A file is read into a `Spec` (every key checked: unknown, missing, wrong type,
non-finite, out of range), the command-line overrides are applied, generators are run
with the run's seed, and the result is checked as a whole (Assumption 1, start
separations, list lengths, the arena, the law's first command). Every refusal is a
ScenarioError naming the file, the key and the reason. Built-in scenarios are written as
the same dictionaries a TOML file parses into, so they pass through the very same checks.

Size: what cannot run is refused before it is built (more than MAX_ROBOTS robots,
MAX_OBSTACLES obstacles, MAX_STEPS steps, coordinates beyond MAX_COORD), and building and
checking are O(N log N): pairs are searched on grids (swarm.core.geometry), never over all
pairs. A large file's pose lists are counted in its text before the TOML parser builds them.
A build or check that takes more than a second reports its progress on stderr
(StderrProgress, or the `progress` callable given to load()).

Randomness: one numpy Generator seeded with run.seed draws, in this order, the random
start poses (robots.random) and then the random assignment of slots to robots.
"""

from __future__ import annotations

import math
import re
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, TextIO, cast

import numpy as np

from swarm.core import generators, kinematics, law, userlaw
from swarm.core.toml_reader import Reader, join, kind, show
from swarm.core.errors import not_utf8
from swarm.core.builtins import BUILTINS as BUILTINS, MAX_ROBOTS as MAX_ROBOTS, builtin_document
from swarm.core.geometry import Counter, Grid, closest_pair
from swarm.core.scenario import THRESHOLDS, Control, Leader, Scenario, ScenarioError, Segment

if TYPE_CHECKING:
    from collections.abc import Iterable

    from swarm.core.faults import Faults


# What a scenario may hold: beyond these a run cannot go (memory, time, float resolution), so a
# scenario is refused before anything is built.
MAX_OBSTACLES = 100_000  # the most a world can send its robots (the obstacles message, swarm.proto.protocol)
MAX_STEPS = 100_000_000
MAX_COORD = 1e6  # m: every |coordinate| and every radius or distance of the file (1e-10 m resolution there)
# what the swarm's messages carry (swarm.proto.protocol: MAX_ANGLE, MAX_SPEED, MAX_TURN, tests hold them equal):
# a scenario beyond them would run in swarm sim and not in swarm up
MAX_ANGLE = 1e6  # rad: |theta| of a start, and the leader's heading over the run (it is not wrapped)
MAX_SPEED = 100.0  # m/s: |v| of a segment, control.v_max
MAX_TURN = 100.0  # rad/s: |w| of a segment, control.w_max
WIRE = "what the swarm's messages carry"

Progress = Callable[[str, int, int], None]  # progress(stage, done, total)


class StderrProgress:
    """The default progress reporter: "scenario: STAGE ...", "scenario: STAGE: DONE of TOTAL" lines on stderr.

    Silent for the first `after_s` seconds (a usual scenario loads in milliseconds and prints
    nothing), then at most one line every `every_s` seconds per stage, plus the first line of each
    new stage; finish() closes with the time taken when anything was printed.
    """

    def __init__(self, stream: TextIO | None = None, after_s: float = 1.0, every_s: float = 1.0,
                 clock: Callable[[], float] = time.monotonic):
        self.stream, self.after_s, self.every_s, self.clock = stream, after_s, every_s, clock
        self.started = clock()
        self.last = -math.inf
        self.stage: str | None = None
        self.printed = False

    def __call__(self, stage: str, done: int, total: int) -> None:
        now = self.clock()
        if now - self.started < self.after_s:
            return
        if stage == self.stage and now - self.last < self.every_s:
            return
        self.stage, self.last, self.printed = stage, now, True
        if done <= 0:
            self._write(f"scenario: {stage} ...")
        elif done >= total:
            self._write(f"scenario: {stage}: done")
        else:
            self._write(f"scenario: {stage}: {done} of {total}")

    def finish(self) -> None:
        if self.printed:
            self._write(f"scenario: ready after {self.clock() - self.started:.1f} s")

    def _write(self, line: str) -> None:
        stream = self.stream if self.stream is not None else sys.stderr
        stream.write(line + "\n")
        stream.flush()


def silent(stage: str, done: int, total: int) -> None:
    """A progress callable that reports nothing (pass progress=silent to load())."""


@dataclass(frozen=True)
class Overrides:
    """Command-line flags; None means "not given" (the file or the default decides)."""

    robots: int | None = None
    seed: int | None = None
    duration: float | None = None
    dt: float | None = None
    governor: bool | None = None
    faults: str | None = None  # --faults FILE: a faults table that replaces the scenario's
    drop: float | None = None  # --drop P: one more drop rule of class "all"
    kill: str | None = None  # --kill ID@T,...: one more kill rule a robot


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
    bounds: tuple[float, float, float, float] | None = None  # m, [arena] bounds
    faults: Any = None  # the [faults] table as parsed TOML (checked once the robots are known: resolve)


# --------------------------------------------------------------------------- reading


class _Reader(Reader):
    """The project's TOML reader (swarm.core.toml_reader), with the scenario's lists of vectors."""

    def vectors(self, value: Any, key: str, length: int, what: str, most: int, bounded: int) -> np.ndarray:
        """A non-empty list of at most `most` vectors; the first `bounded` numbers of each within MAX_COORD."""
        if not isinstance(value, list) or not value:
            raise self.fail(key, f"must be a non-empty list of [{what}], got {show(value)}")
        if len(value) > most:
            raise self.fail(key, f"lists {len(value)} entries; a scenario has at most {most} robots")
        out = np.array([self.vector(v, f"{key}[{i}]", length, what) for i, v in enumerate(value)], float)
        _within(self, out[:, :bounded], key)
        return out


def _within(rd: _Reader, values: np.ndarray, key: str, bound: float = MAX_COORD, unit: str = "m in size",
            first: int = 0) -> None:
    """Refuse the first entry of a (K, C) array whose size exceeds bound, naming key[k][first + c]."""
    bad = np.abs(values) > bound
    if bad.any():
        k, c = map(int, np.argwhere(bad)[0])
        raise rd.fail(f"{key}[{k}][{first + c}]", f"must be at most {bound:g} {unit}, got {values[k, c]:g}")





def parse(doc: dict[str, Any], where: str, name: str, builtin: str | None = None) -> Spec:
    """Check a parsed TOML document (docs/scenarios.md) and return its Spec."""
    rd = _Reader(where)
    rd.table(doc, "", ("run", "control", "bodies", "arena", "leader", "formation", "robots", "obstacles", "faults"),
             ("run", "leader", "formation", "robots"))

    run = rd.table(doc["run"], "run", ("duration", "dt", "seed"), ("duration",))
    duration = rd.number(run["duration"], "run.duration", gt=0)
    dt = rd.number(run.get("dt", 0.001), "run.dt", gt=0)
    seed = rd.integer(run.get("seed", 0), "run.seed")

    ctl = rd.table(doc.get("control", {}), "control",
                   ("k1", "k2", "k3", "tu", "vt", "threshold", "governor", "v_max", "w_max", "law", "params", "memory"))
    defaults = Control()
    control = Control(
        k1=rd.number(ctl.get("k1", defaults.k1), "control.k1", gt=0),
        k2=rd.number(ctl.get("k2", defaults.k2), "control.k2", gt=0),
        k3=rd.number(ctl.get("k3", defaults.k3), "control.k3", gt=0),
        tu=rd.number(ctl.get("tu", defaults.tu), "control.tu", gt=0),
        vt=rd.number(ctl.get("vt", defaults.vt), "control.vt", ge=0),
        threshold=rd.choice(ctl.get("threshold", defaults.threshold), "control.threshold", tuple(THRESHOLDS)),
        governor=rd.boolean(ctl.get("governor", defaults.governor), "control.governor"),
        v_max=rd.number(ctl["v_max"], "control.v_max", gt=0, bound=MAX_SPEED, why=WIRE) if "v_max" in ctl else None,
        w_max=rd.number(ctl["w_max"], "control.w_max", gt=0, bound=MAX_TURN, why=WIRE) if "w_max" in ctl else None,
        law=userlaw.parse_control(rd, ctl, None if builtin else Path(where).resolve().parent),
    )

    bodies = rd.table(doc.get("bodies", {}), "bodies", ("r", "R"))
    r = rd.number(bodies.get("r", 0.3), "bodies.r", gt=0, bound=MAX_COORD)
    R = rd.number(bodies.get("R", 1.2), "bodies.R", gt=0, bound=MAX_COORD)
    if not r < R:
        raise rd.fail("bodies.R", f"must be larger than bodies.r = {r:g}, got {R:g}")

    bounds = None
    arena = rd.table(doc.get("arena", {}), "arena", ("bounds",))
    if "bounds" in arena:  # an [arena] table without bounds: no arena, as without the table
        box = rd.vector(arena["bounds"], "arena.bounds", 4, "xmin, xmax, ymin, ymax", bound=MAX_COORD)
        if not (box[0] < box[1] and box[2] < box[3]):
            raise rd.fail("arena.bounds", f"must have xmin < xmax and ymin < ymax, got {box}")
        bounds = cast("tuple[float, float, float, float]", tuple(box))

    ld = rd.table(doc["leader"], "leader", ("start", "segments"), ("start", "segments"))
    start = rd.vector(ld["start"], "leader.start", 3, "x, y, theta")
    for c in range(2):
        rd.number(start[c], f"leader.start[{c}]", bound=MAX_COORD)
    rd.number(start[2], "leader.start[2]", bound=MAX_ANGLE, why=WIRE)
    if not isinstance(ld["segments"], list) or not ld["segments"]:
        raise rd.fail("leader.segments", f"must be a non-empty list of {{duration, v, w}}, got {show(ld['segments'])}")
    segments = []
    for i, seg in enumerate(ld["segments"]):
        key = f"leader.segments[{i}]"
        rd.table(seg, key, ("duration", "v", "w"), ("duration", "v", "w"))
        segments.append(Segment(rd.number(seg["duration"], f"{key}.duration", gt=0),
                                rd.number(seg["v"], f"{key}.v", bound=MAX_SPEED, why=WIRE),
                                rd.number(seg["w"], f"{key}.w", bound=MAX_TURN, why=WIRE)))
    leader = Leader(cast("tuple[float, float, float]", tuple(start)), tuple(segments))

    fm = rd.table(doc["formation"], "formation", ("offsets", "hex", "assignment"))
    offsets = hex_ = None
    if ("offsets" in fm) == ("hex" in fm):
        raise rd.fail("formation", "give exactly one of 'offsets' (a list of [dx, dy]) or 'hex' (a generator)")
    if "offsets" in fm:
        offsets = rd.vectors(fm["offsets"], "formation.offsets", 2, "dx, dy", MAX_ROBOTS, 2)
    else:
        hx = rd.table(fm["hex"], "formation.hex", ("count", "spacing"), ("count", "spacing"))
        hex_ = (_robot_count(rd, hx["count"], "formation.hex.count"),
                rd.number(hx["spacing"], "formation.hex.spacing", gt=0, bound=MAX_COORD))
    assignment = rd.choice(fm.get("assignment", "ordered"), "formation.assignment", ("ordered", "random"))

    rb = rd.table(doc["robots"], "robots", ("poses", "random"))
    poses = random = None
    if ("poses" in rb) == ("random" in rb):
        raise rd.fail("robots", "give exactly one of 'poses' (a list of [x, y, theta]) or 'random' (a generator)")
    if "poses" in rb:
        poses = rd.vectors(rb["poses"], "robots.poses", 3, "x, y, theta", MAX_ROBOTS, 2)
        _within(rd, poses[:, 2:], "robots.poses", MAX_ANGLE, f"rad in size ({WIRE})", first=2)
    else:
        key = "robots.random"
        rnd = rd.table(rb["random"], key, ("count", "region", "min_separation", "obstacle_clearance"),
                       ("count", "region"))
        region = rd.vector(rnd["region"], f"{key}.region", 4, "xmin, xmax, ymin, ymax", bound=MAX_COORD)
        if not (region[0] < region[1] and region[2] < region[3]):
            raise rd.fail(f"{key}.region", f"must have xmin < xmax and ymin < ymax, got {region}")
        random = {
            "count": _robot_count(rd, rnd["count"], f"{key}.count"),
            "region": tuple(region),
            "min_separation": rd.number(rnd.get("min_separation", 2 * r), f"{key}.min_separation", ge=0,
                                        bound=MAX_COORD),
            "obstacle_clearance": rd.number(rnd.get("obstacle_clearance", R), f"{key}.obstacle_clearance", ge=0,
                                            bound=MAX_COORD),
        }

    obstacles = _parse_obstacles(rd, doc.get("obstacles", []), r, R)
    return Spec(where, name, duration, dt, seed, control, r, R, leader, offsets, hex_, assignment,
                poses, random, obstacles, builtin, bounds, doc.get("faults"))


def _robot_count(rd: _Reader, value: Any, key: str) -> int:
    n = rd.integer(value, key, ge=1)
    if n > MAX_ROBOTS:
        raise rd.fail(key, f"must be at most {MAX_ROBOTS} (the most robots a scenario can hold), got {n}")
    return n


def _parse_obstacles(rd: _Reader, value: Any, r: float, R: float) -> np.ndarray:
    if not isinstance(value, list):
        raise rd.fail("obstacles", f"must be an array of tables ([[obstacles]]), got {kind(value)}")
    if len(value) > MAX_OBSTACLES:
        raise rd.fail("obstacles", f"lists {len(value)} obstacles; a scenario has at most {MAX_OBSTACLES}")
    parts: list[np.ndarray] = []
    total = 0
    for i, ob in enumerate(value):
        key = f"obstacles[{i}]"
        rd.table(ob, key, ("center", "row", "r", "R"))
        orr = rd.number(ob.get("r", r), f"{key}.r", gt=0, bound=MAX_COORD)
        oR = rd.number(ob.get("R", R), f"{key}.R", gt=0, bound=MAX_COORD)
        if not orr < oR:
            raise rd.fail(f"{key}.R", f"must be larger than r = {orr:g}, got {oR:g}")
        if ("center" in ob) == ("row" in ob):
            raise rd.fail(key, "give exactly one of 'center' = [x, y] or 'row' = {start, end, pitch}")
        if "center" in ob:
            centres = np.array([rd.vector(ob["center"], f"{key}.center", 2, "x, y", bound=MAX_COORD)])
        else:
            row = rd.table(ob["row"], f"{key}.row", ("start", "end", "pitch"), ("start", "end", "pitch"))
            a = rd.vector(row["start"], f"{key}.row.start", 2, "x, y", bound=MAX_COORD)
            b = rd.vector(row["end"], f"{key}.row.end", 2, "x, y", bound=MAX_COORD)
            pitch = rd.number(row["pitch"], f"{key}.row.pitch", gt=0)
            intervals = math.dist(a, b) / pitch  # about the row's obstacles, counted before they are made
            if total + intervals > MAX_OBSTACLES:
                raise rd.fail(f"{key}.row", f"makes about {intervals:.4g} obstacles (length / pitch), more than "
                              f"the {MAX_OBSTACLES} a scenario can hold: give a larger pitch")
            centres = generators.obstacle_row(a, b, pitch)
        total += len(centres)
        if total > MAX_OBSTACLES:
            raise rd.fail(key, f"makes {total} obstacles in all; a scenario has at most {MAX_OBSTACLES}")
        part = np.empty((len(centres), 4))
        part[:, :2], part[:, 2], part[:, 3] = centres, orr, oR
        parts.append(part)
    return np.concatenate(parts) if parts else np.zeros((0, 4))


# --------------------------------------------------------------------------- resolving


def resolve(spec: Spec, ov: Overrides = Overrides(), progress: Progress = silent,
            counter: Counter | None = None) -> Scenario:
    """Apply the overrides, run the generators and check the scenario as a whole.

    progress(stage, done, total) hears about the long steps; counter adds up the pair checks."""
    rd = _Reader(spec.where)
    for flag, value in (("--seed", ov.seed), ("--duration", ov.duration), ("--dt", ov.dt), ("--robots", ov.robots)):
        if value is not None and not (math.isfinite(value) and value > (-1 if flag == "--seed" else 0)):
            raise ScenarioError("command line", flag, f"must be {'>= 0' if flag == '--seed' else '> 0'}, got {value}")
    if ov.robots is not None and ov.robots > MAX_ROBOTS:
        raise ScenarioError("command line", "--robots", f"must be at most {MAX_ROBOTS} (the most robots a scenario "
                            f"can hold), got {ov.robots}")
    if ov.robots is not None and spec.builtin is not None:
        spec = parse(builtin_document(spec.builtin, ov.robots), spec.where, spec.name, spec.builtin)
    seed = spec.seed if ov.seed is None else ov.seed
    duration = spec.duration if ov.duration is None else ov.duration
    dt = spec.dt if ov.dt is None else ov.dt
    _check_steps(spec, ov, duration, dt)
    control = spec.control
    if ov.governor is not None:
        control = Control(**{**control.__dict__, "governor": ov.governor})
    rng = np.random.default_rng(seed)

    offsets = cast(np.ndarray, spec.offsets)  # None only with spec.hex, which replaces it
    if spec.hex is not None:
        count = spec.hex[0] if ov.robots is None else ov.robots
        offsets = generators.hex_patch(count, spec.hex[1])
    elif ov.robots is not None and len(offsets) != ov.robots:
        raise rd.fail("formation.offsets", f"lists {len(offsets)} offsets explicitly; --robots {ov.robots} only "
                      "resizes scenarios made by generators (formation.hex, robots.random)")

    poses = cast(np.ndarray, spec.poses)  # None only with spec.random, which replaces it
    if spec.random is not None:
        g = spec.random
        count = g["count"] if ov.robots is None else ov.robots
        try:
            poses = generators.random_poses(rng, count, g["region"], g["min_separation"], spec.obstacles,
                                            g["obstacle_clearance"], progress=progress, counter=counter)
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
                   np.ascontiguousarray(spec.obstacles, float).reshape(-1, 4), spec.bounds)
    check(scn, spec.where, offsets_key="formation.hex" if spec.hex else "formation.offsets",
          poses_key="robots.random" if spec.random else "robots.poses", progress=progress, counter=counter)
    return scn.replace(faults=_resolve_faults(spec, ov, scn))


def _resolve_faults(spec: Spec, ov: Overrides, scn: Scenario) -> Faults | None:
    """The run's faults: the file's [faults] table (or --faults FILE instead), plus the --drop and --kill
    shorthands; None when there is no fault at all (the simulator then runs its fault-free kernel)."""
    from swarm.core import faults as fl

    if ov.faults is not None:
        if spec.faults is not None:  # replaced, but still checked: a broken file is refused whatever replaces it
            # (ids against what a scenario can hold: --robots may have resized the file's robots below them)
            fl.parse_faults(spec.faults, spec.where, MAX_ROBOTS, scn.duration, scn.seed)
        f = fl.load_faults_file(ov.faults, scn.n, scn.duration, scn.seed)
    elif spec.faults is not None:
        f = fl.parse_faults(spec.faults, spec.where, scn.n, scn.duration, scn.seed)
    else:
        f = fl.Faults.empty(scn.seed % fl.SEED_LIMIT)
    drops = [fl.drop_shorthand(ov.drop)] if ov.drop is not None else []
    kills = list(fl.kill_shorthand(ov.kill, scn.n, scn.duration)) if ov.kill is not None else []
    if drops or kills:
        f = fl.merged(f, drops=drops, kills=kills)
    return f if f else None


def _check_steps(spec: Spec, ov: Overrides, duration: float, dt: float) -> None:
    """A run of at least one whole step and at most MAX_STEPS steps; the message names where dt and the
    duration came from (the file's keys or the flags)."""
    dt_key = "--dt" if ov.dt is not None else "run.dt"
    dur_key = "--duration" if ov.duration is not None else "run.duration"
    where = "command line" if ov.dt is not None and ov.duration is not None else spec.where
    if dt > duration:
        raise ScenarioError(where, dt_key, f"dt = {dt:g} s is longer than the run ({dur_key} = {duration:g} s): "
                            "a run needs dt <= duration")
    steps = duration / dt
    if steps > MAX_STEPS:
        raise ScenarioError(where, f"{dur_key} / {dt_key}", f"{duration:g} s in steps of {dt:g} s is {steps:.4g} "
                            f"steps; a run has at most {MAX_STEPS:.0e} steps: shorten the run or lengthen dt")


def _leader_heading(scn: Scenario, where: str) -> None:
    """The leader's heading (not wrapped) within MAX_ANGLE for the whole run: its references carry it."""
    theta, t = float(scn.leader.start[2]), 0.0
    segments = scn.leader.segments
    until = (scn.steps + 1) * scn.dt  # the leader answers the last tick's clock with the next tick's reference
    for k, seg in enumerate(segments):
        span = max(0.0, until - t) if k == len(segments) - 1 else min(seg.duration, max(0.0, until - t))
        theta += seg.w * span
        t += span
        if abs(theta) > MAX_ANGLE:
            raise ScenarioError(where, f"leader.segments[{k}].w", f"the leader's heading reaches {theta:.4g} rad by "
                                f"t = {t:g} s; it must stay within {MAX_ANGLE:g} rad in size ({WIRE})")


def check(scn: Scenario, where: str, offsets_key: str = "formation.offsets", poses_key: str = "robots.poses",
          progress: Progress = silent, counter: Counter | None = None) -> None:
    """The scenario as a whole: sizes, the arena, Assumption 1, the start separations and the law's
    first command (all O(N log N)). Raises ScenarioError naming `where`, the key and the reason."""
    if scn.n > MAX_ROBOTS:
        raise ScenarioError(where, poses_key, f"{scn.n} robots; a scenario has at most {MAX_ROBOTS}")
    for key, what, values in ((offsets_key, "slot offset", scn.offsets), (poses_key, "start", scn.poses[:, :2])):
        bad = np.abs(values) > MAX_COORD
        if bad.any():
            i, c = map(int, np.argwhere(bad)[0])
            raise ScenarioError(where, key, f"robot {i}'s {what} has {'xy'[c]} = {values[i, c]:g} m; every coordinate "
                                f"must be at most {MAX_COORD:g} m in size")
    _leader_heading(scn, where)
    if scn.bounds is not None:
        xmin, xmax, ymin, ymax = scn.bounds
        x, y = scn.poses[:, 0], scn.poses[:, 1]
        out = np.flatnonzero((x < xmin) | (x > xmax) | (y < ymin) | (y > ymax))
        if out.size:
            i = int(out[0])
            raise ScenarioError(where, poses_key, f"robot {i} starts at ({x[i]:g}, {y[i]:g}), outside arena.bounds "
                                f"[{xmin:g}, {xmax:g}, {ymin:g}, {ymax:g}] ({out.size} robots outside)")
    progress("checking the formation's slots", 0, scn.n)
    pair = closest_pair(scn.offsets, scn.R, counter)
    if pair is not None:
        i, j, d = pair
        raise ScenarioError(where, offsets_key, f"slots of robots {i} and {j} are {d:.4g} m apart; "
                            f"formation offsets must be more than R = {scn.R:g} m apart (Assumption 1)")
    progress("checking the start separations", 0, scn.n)
    pair = closest_pair(scn.poses[:, :2], scn.r, counter)
    if pair is not None and pair[2] < scn.r:
        i, j, d = pair
        raise ScenarioError(where, poses_key, f"robots {i} and {j} start {d:.4g} m apart, closer than r = {scn.r:g} m")
    hit = _obstacles_within(scn, scn.obstacles[:, 2], counter)
    if hit is not None:
        i, o, d = hit
        raise ScenarioError(where, poses_key, f"robot {i} starts {d:.4g} m from obstacle {o} "
                            f"at ({scn.obstacles[o, 0]:g}, {scn.obstacles[o, 1]:g}), closer than its "
                            f"r = {scn.obstacles[o, 2]:g} m")
    _check_first_commands(scn, where, progress, counter)


def _obstacles_within(scn: Scenario, limit: np.ndarray, counter: Counter | None) -> tuple[int, int, float] | None:
    """The first (robot i, obstacle o, distance d [m]) with a start closer than limit[o] [m] to obstacle o's
    centre, in (i, o) order, or None. Obstacles are searched in groups of like limit (a power of two
    apart at most), each on a grid of its own cells, so a few huge obstacles do not coarsen the grid
    of the many small ones."""
    if not len(scn.obstacles) or not scn.n:
        return None
    groups = np.ceil(np.log2(limit)).astype(np.int64)
    found = []
    pos = scn.poses[:, :2]
    for g in np.unique(groups):
        members = np.flatnonzero(groups == g)
        side = float(limit[members].max())
        i, k, d2 = Grid(scn.obstacles[members, :2], side).pairs(pos, side, counter)
        d = np.sqrt(d2)
        o = members[k]
        bad = d < limit[o]
        if bad.any():
            found.append((i[bad], o[bad], d[bad]))
    if not found:
        return None
    i, o, d = (np.concatenate(parts) for parts in zip(*found))
    first = int(np.lexsort((o, i))[0])
    return int(i[first]), int(o[first]), float(d[first])


def _check_first_commands(scn: Scenario, where: str, progress: Progress, counter: Counter | None) -> None:
    """Refuse a scenario whose law is already non-finite at t = 0 (gains so large that k1 times the
    distance to the slot overflows, say): the simulator would stop at its first step."""
    if scn.control.law is not None:
        return  # a user's law: `swarm scenario check` test-calls it (swarm.core.userlaw.check)
    cmd = first_commands(scn, progress, counter)
    bad = np.flatnonzero(~np.isfinite(cmd).all(axis=1))
    if bad.size:
        k, c = int(bad[0]), scn.control
        x, y = scn.poses[k, :2]
        xl, yl = scn.leader.start[:2]
        raise ScenarioError(where, "control", f"robot {k}'s command at t = 0 is not finite (v = {cmd[k, 0]:g} m/s, "
                            f"w = {cmd[k, 1]:g} rad/s) with k1 = {c.k1:g}, k2 = {c.k2:g}, k3 = {c.k3:g}: it starts "
                            f"{math.hypot(xl + scn.offsets[k, 0] - x, yl + scn.offsets[k, 1] - y):.4g} m from its "
                            f"slot ({bad.size} of the {scn.n} robots are); lower the gains")


def first_commands(scn: Scenario, progress: Progress = silent, counter: Counter | None = None) -> np.ndarray:
    """(N, 2) every robot's command v [m/s], w [rad/s] at t = 0, as the simulator's first step computes it.

    The law of swarm.core.law in plain Python, per robot, with its known bodies: the robots and
    obstacles closer than the cell side, robots by ascending id, then obstacles by ascending index
    (the summation order of every run). Where plain Python raises (an overflowing exp, say) the
    compiled law would give inf or nan: the command is then nan. O(N) on grids.
    """
    n, p = scn.n, scn.params()
    sense = float(p[law.P_SENSE])
    xl, yl, thl, vl, wl = map(float, kinematics.leader_state(scn.leader.table(), 0.0))
    pos = scn.poses[:, :2]
    within2 = sense * sense
    i, j, d2 = Grid(pos, sense).pairs(pos, sense, counter, same=True)
    near = d2 < within2
    src = np.concatenate((i[near], j[near]))
    dst = np.concatenate((j[near], i[near]))
    order = np.lexsort((dst, src))
    src, dst = src[order], dst[order]
    robot_start = np.searchsorted(src, np.arange(n + 1))
    oi = oo = np.zeros(0, np.int64)
    if len(scn.obstacles):
        oi, oo, od2 = Grid(scn.obstacles[:, :2], sense).pairs(pos, sense, counter)
        near = od2 < within2
        order = np.lexsort((oo[near], oi[near]))
        oi, oo = oi[near][order], oo[near][order]
    obstacle_start = np.searchsorted(oi, np.arange(n + 1))
    q, off, obs = scn.poses.tolist(), scn.offsets.tolist(), scn.obstacles.tolist()
    dst, near_obstacles = dst.tolist(), oo.tolist()
    rs, ro = robot_start.tolist(), obstacle_start.tolist()
    r, R = float(scn.r), float(scn.R)
    params = p.tolist()
    out = np.empty((n, 2))
    for k in range(n):
        if k % 4096 == 0:
            progress("evaluating the law at t = 0", k, n)
        nx, ny, nr, nR, nk = [], [], [], [], []
        for j in dst[rs[k]:rs[k + 1]]:
            nx.append(q[j][0])
            ny.append(q[j][1])
            nr.append(r)
            nR.append(R)
            nk.append(law.KIND_ROBOT)
        for o in near_obstacles[ro[k]:ro[k + 1]]:
            ob = obs[o]
            nx.append(ob[0])
            ny.append(ob[1])
            nr.append(ob[2])
            nR.append(ob[3])
            nk.append(law.KIND_OBSTACLE)
        mem = [0.0] * law.M_SIZE
        mem[law.M_SCALE] = 1.0
        x, y, th = q[k]
        try:
            out[k] = law.robot_command(x, y, th, off[k][0], off[k][1], r, 0.0, xl, yl, thl, vl, wl,
                                       nx, ny, nr, nR, nk, [0.0] * len(nx), len(nx), mem, params)
        except (OverflowError, ValueError, ZeroDivisionError):
            out[k] = math.nan
    return out


STEEP_START = 0.02  # share of (R - r): a start this close above r is allowed but warned about
FAR_LEADER = MAX_COORD  # m: a leader that may travel farther than this is warned about


def advisories(scn: Scenario, counter: Counter | None = None) -> list[str]:
    """Valid but odd or risky choices, to warn about (the contract accepts them)."""
    out = []
    hint = "" if scn.control.governor else " (the governor, --governor, limits that)"
    pair = closest_pair(scn.poses[:, :2], scn.r + STEEP_START * (scn.R - scn.r), counter)
    if pair is not None and pair[2] < scn.r + STEEP_START * (scn.R - scn.r):
        i, j, d = pair
        out.append(f"robots {i} and {j} start {d:.4g} m apart, just outside r = {scn.r:g} m: the repulsion there is "
                   f"so steep that one step can throw them far apart{hint}")
    ro, Ro = scn.obstacles[:, 2], scn.obstacles[:, 3]
    hit = _obstacles_within(scn, ro + STEEP_START * (Ro - ro), counter)
    if hit is not None:
        i, o, d = hit
        out.append(f"robot {i} starts {d:.4g} m from obstacle {o}, just outside its r = "
                   f"{scn.obstacles[o, 2]:g} m: the repulsion there is so steep that one step can throw the "
                   f"robot far away{hint}")
    c, segs = scn.control, scn.leader.segments
    reach = float(np.max(np.hypot(scn.offsets[:, 0], scn.offsets[:, 1]))) if scn.n else 0.0
    # slots are the leader's position plus fixed offsets: they move at the leader's v plus w times the offset
    slot_speed = [abs(s.v) + abs(s.w) * reach for s in segs]
    fastest = int(np.argmax(slot_speed))
    if c.v_max is not None and slot_speed[fastest] > c.v_max:
        out.append(f"leader.segments[{fastest}] moves the formation's slots at up to {slot_speed[fastest]:.4g} m/s, "
                   f"faster than control.v_max = {c.v_max:g} m/s: the robots cannot keep up")
    turn = int(np.argmax([abs(s.w) for s in segs]))
    if c.w_max is not None and abs(segs[turn].w) > c.w_max:
        out.append(f"leader.segments[{turn}] turns at {abs(segs[turn].w):g} rad/s, faster than control.w_max = "
                   f"{c.w_max:g} rad/s: the robots cannot turn with it")
    if scn.duration < c.tu:
        out.append(f"run.duration = {scn.duration:g} s is shorter than control.tu = {c.tu:g} s: a frozen robot's "
                   "reference snapshot is never refreshed")
    step = slot_speed[fastest] * scn.dt
    share = (scn.cell_side - scn.reach) / 3.0
    if step > share:
        out.append(f"at dt = {scn.dt:g} s the slots move up to {step:.4g} m a step (leader.segments[{fastest}]), "
                   f"more than (cell side - reach) / 3 = {share:.4g} m: robots that keep up move as far, and "
                   "swarm up's lock-step may then differ from swarm sim (docs/runtime.md)")
    travel = _leader_travel(scn)
    if travel > FAR_LEADER:
        out.append(f"the leader may travel {travel:.4g} m during the run, beyond {FAR_LEADER:g} m: positions "
                   "lose resolution there and may overflow")
    if scn.bounds is not None:
        out.extend(_arena_advisories(scn))
    if scn.faults:
        from swarm.core.faults import advisories as fault_advisories

        out += fault_advisories(scn.faults, scn.steps * scn.dt, scn.n)  # the last step's time: a fault there acts
    return out


def _leader_travel(scn: Scenario) -> float:
    """A bound of the distance [m] the leader covers in the run: the sum of |v| times each segment's time."""
    total, t = 0.0, 0.0
    for k, seg in enumerate(scn.leader.segments):
        last = k == len(scn.leader.segments) - 1
        span = max(0.0, scn.duration - t) if last else min(seg.duration, max(0.0, scn.duration - t))
        total += abs(seg.v) * span
        t += seg.duration
    return total


def _arena_advisories(scn: Scenario) -> list[str]:
    """The formation's slots leaving the arena, sampled along the leader's path (at most 2001 times)."""
    xmin, xmax, ymin, ymax = cast("tuple[float, float, float, float]", scn.bounds)  # advisories() checks it
    lo, hi = scn.offsets.min(axis=0), scn.offsets.max(axis=0)
    table = scn.leader.table()
    for t in np.linspace(0.0, scn.duration, int(min(2001, scn.steps + 1))):
        x, y = kinematics.leader_state(table, float(t))[:2]
        if x + lo[0] < xmin or x + hi[0] > xmax or y + lo[1] < ymin or y + hi[1] > ymax:
            return [f"the formation's slots leave arena.bounds [{xmin:g}, {xmax:g}, {ymin:g}, {ymax:g}] at t = "
                    f"{t:.4g} s (the leader is at ({x:.4g}, {y:.4g})): the robots follow them out (in real time "
                    "each robot's drive halts it at the edge; swarm sim and lock-step, which have no drive, do not)"]
    return []


def read_spec(source: str, progress: Progress = silent) -> Spec:
    """A built-in name or a path to a TOML file, checked."""
    if source in BUILTINS:
        return parse(builtin_document(source), f"built-in scenario '{source}'", source, builtin=source)
    path = Path(source)
    if path.is_dir():
        raise ScenarioError(source, "", "is a directory; give a scenario file (TOML) in it, or a built-in "
                                        f"({', '.join(BUILTINS)})")
    if path.exists() and not path.is_file():
        raise ScenarioError(source, "", "is not a regular file (a FIFO, a device or a socket); give a file")
    if not path.is_file():
        hint = "" if source.endswith(".toml") else f" (built-ins: {', '.join(BUILTINS)})"
        raise ScenarioError(source, "", f"no such file{hint}")
    try:
        raw = path.read_bytes()
        progress(f"reading {source} ({len(raw) / 1e6:.1f} MB)", 0, 1)
        if len(raw) > PRESCAN_BYTES:
            _prescan(raw, source)
        doc = tomllib.loads(raw.decode("utf-8"))
        progress(f"reading {source} ({len(raw) / 1e6:.1f} MB)", 1, 1)
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(source, "", f"not valid TOML: {e}") from None
    except UnicodeDecodeError as e:
        raise not_utf8(source, raw, e) from None
    except OSError as e:
        raise ScenarioError(source, "", f"cannot read: {e.strerror or e}") from None
    return parse(doc, source, path.stem)


# A file larger than this is pre-scanned: its pose and offset lists are counted in its text before the
# TOML parser turns them into objects (~5 s and ~100 MB per 10 MB of text). 10^5 poses need more text.
PRESCAN_BYTES = 512 * 1024
_STRINGS_AND_COMMENTS = re.compile(rb'"""[\s\S]*?"""|\'\'\'[\s\S]*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*')
_LIST_KEY = re.compile(rb"\b(poses|offsets)\s*=\s*\[")
_EMPTY_LIST = re.compile(rb"\s*\]")
_LIST_END = re.compile(rb"\]\s*,?\s*\]")  # the last entry's "]" and the list's own
_OBSTACLE_TABLE = re.compile(rb"^\s*\[\[\s*obstacles\s*\]\]", re.MULTILINE)


def _prescan(raw: bytes, where: str) -> None:
    """Refuse a file whose `poses` or `offsets` list holds more than MAX_ROBOTS entries, or which has more
    than MAX_OBSTACLES [[obstacles]] tables, from its text (C-speed regular expressions, ~1 s for 50 MB),
    before the TOML parser builds them. Strings and comments are blanked first; the counts only
    refuse what the parsed file would be refused for, so anything else is left to the parser."""
    text = _STRINGS_AND_COMMENTS.sub(b"", raw)
    for m in _LIST_KEY.finditer(text):
        end = _LIST_END.search(text, m.end())
        if _EMPTY_LIST.match(text, m.end()) or end is None:
            continue
        count = text.count(b"[", m.end(), end.start())
        if count > MAX_ROBOTS:
            key = "robots.poses" if m.group(1) == b"poses" else "formation.offsets"
            raise ScenarioError(where, key, f"lists {count} entries; a scenario has at most {MAX_ROBOTS} robots")
    tables = sum(1 for _ in _OBSTACLE_TABLE.finditer(text))
    if tables > MAX_OBSTACLES:
        raise ScenarioError(where, "obstacles", f"lists {tables} obstacles; a scenario has at most {MAX_OBSTACLES}")


def load(source: str, overrides: Overrides = Overrides(), progress: Progress | None = None,
         counter: Counter | None = None) -> Scenario:
    """Read, check and resolve a scenario (a built-in name or a TOML path).

    progress: called as progress(stage, done, total) during long steps; None: a StderrProgress
    (lines on stderr only when loading takes more than a second); `silent` for none.
    counter: adds up the pair checks of the searches (for tests of the work)."""
    reporter = StderrProgress() if progress is None else progress
    scn = resolve(read_spec(source, reporter), overrides, reporter, counter)
    if isinstance(reporter, StderrProgress):
        reporter.finish()
    return scn


SCALE_SHARE = 0.8  # a scaled leader uses this share of the robot's limits (the pre-flight's, inventory.PREFLIGHT_SHARE)


def scaled(scn: Scenario, v_max: float, w_max: float | None = None) -> tuple[Scenario, float]:
    """`scn` with its leader slowed down by k <= 1 so that in every segment the formation's slots move at most
    SCALE_SHARE v_max (|v| + |w| times the farthest slot's offset, as advisories() bounds them) and turn at most
    SCALE_SHARE w_max: each segment's v and w times k (its arc keeps its curvature, so the path is the same) and
    its duration over k, the run's duration over k; control.v_max and w_max become the limits given (never
    looser than the scenario's). Returns (the scenario, k)."""
    import dataclasses

    segs = scn.leader.segments
    k = 1.0
    reach = float(np.max(np.hypot(scn.offsets[:, 0], scn.offsets[:, 1]))) if scn.n else 0.0
    top_v = max((abs(g.v) + abs(g.w) * reach for g in segs), default=0.0)
    if top_v > SCALE_SHARE * v_max:
        k = min(k, SCALE_SHARE * v_max / top_v)
    top_w = max((abs(g.w) for g in segs), default=0.0)
    if w_max is not None and top_w > SCALE_SHARE * w_max:
        k = min(k, SCALE_SHARE * w_max / top_w)
    leader = dataclasses.replace(scn.leader, segments=tuple(
        dataclasses.replace(g, duration=g.duration / k, v=g.v * k, w=g.w * k) for g in segs))
    c = scn.control
    def tighter(old: float | None, new: float | None) -> float | None:
        return old if new is None else new if old is None else min(old, new)
    control = dataclasses.replace(c, v_max=tighter(c.v_max, v_max), w_max=tighter(c.w_max, w_max))
    return dataclasses.replace(scn, duration=scn.duration / k, leader=leader, control=control), k


def _quote(text: str) -> str:
    """A TOML basic string."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def to_toml(scn: Scenario, written_by: str = "swarm scenario show") -> str:
    """The resolved scenario as a TOML file with explicit lists (loads back to the same numbers); its first line, a
    comment, names what wrote it (part of the run's digest: swarm.core.runid keeps the default)."""

    def num(x: float) -> str:
        return repr(float(x))

    def vec(v: Iterable[float]) -> str:
        return "[" + ", ".join(num(x) for x in v) + "]"

    c = scn.control
    lines = [
        f"# scenario '{scn.name}': {scn.n} robots, {len(scn.obstacles)} obstacles (written by {written_by})",
        "[run]", f"duration = {num(scn.duration)}", f"dt = {num(scn.dt)}", f"seed = {scn.seed}", "",
        "[control]", f"k1 = {num(c.k1)}", f"k2 = {num(c.k2)}", f"k3 = {num(c.k3)}", f"tu = {num(c.tu)}",
        f"vt = {num(c.vt)}", f'threshold = "{c.threshold}"', f"governor = {'true' if c.governor else 'false'}",
        *(f"{k} = {num(v)}" for k, v in (("v_max", c.v_max), ("w_max", c.w_max)) if v is not None),
        *([] if c.law is None else [f"law = {_quote(c.law.ref)}  # sha256 {c.law.sha256}",
                                    f"params = {vec(c.law.params)}", f"memory = {c.law.memory}"]), "",
        "[bodies]", f"r = {num(scn.r)}", f"R = {num(scn.R)}", "",
        *(["[arena]", f"bounds = {vec(scn.bounds)}", ""] if scn.bounds is not None else []),
        "[leader]", f"start = {vec(scn.leader.start)}", "segments = [",
        *[f"  {{ duration = {num(s.duration)}, v = {num(s.v)}, w = {num(s.w)} }}," for s in scn.leader.segments],
        "]", "",
        "[formation]", 'assignment = "ordered"', "offsets = [", *[f"  {vec(o)}," for o in scn.offsets], "]", "",
        "[robots]", "poses = [", *[f"  {vec(q)}," for q in scn.poses], "]",
    ]
    for x, y, r, R in scn.obstacles:
        lines += ["", "[[obstacles]]", f"center = {vec((x, y))}", f"r = {num(r)}", f"R = {num(R)}"]
    if scn.faults:
        from swarm.core.faults import to_toml as faults_toml

        lines += ["", faults_toml(scn.faults).rstrip("\n")]
    return "\n".join(lines) + "\n"

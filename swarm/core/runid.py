"""A run's identity: its id, the digest of its resolved scenario, and each robot's slice of it.

    d = digest(scn)                         # sha256 of the scenario as canonical TOML (faults included)
    run = new_run_id(clock)                 # "20261202T031502-9f3ab2": unique per run
    cfg = robot_config(scn, i, lockstep, run, d)     # what robot i is given (swarm.proto.protocol.Config)
    first_difference(my_toml, their_toml)  # "control.k1: 0.5 here, 0.6 in the run" or None

Long-lived robots and leaders serve many runs: a new run id tells them to start afresh (tick state,
windows, controller). A process given its own scenario compares digests and refuses a run of another
scenario, naming the first difference, instead of silently spoiling it.
"""

from __future__ import annotations

import time
import tomllib
from typing import TYPE_CHECKING, Any, cast

from msgspec.structs import replace

if TYPE_CHECKING:
    from swarm.core.clock import FakeClock, WallClock
    from swarm.core.faults import Faults
    from swarm.core.scenario import Scenario
    from swarm.proto.protocol import Config


def canonical(scn: Scenario) -> str:
    """The resolved scenario as canonical TOML (explicit lists, every setting): what the digest hashes."""
    from swarm.core.scenario_file import to_toml

    return to_toml(scn)


def digest(scn: Scenario) -> str:
    """Hex sha256 of the canonical scenario."""
    import hashlib  # here: a robot process never needs it (libcrypto is ~3 MiB of its memory)

    return hashlib.sha256(canonical(scn).encode("utf-8")).hexdigest()


def new_run_id(clock: WallClock | FakeClock | None = None) -> str:
    """A run id: the wall-clock start (UTC, to the second) and 6 random hex digits."""
    now = clock.time() if clock is not None else time.time()
    import secrets  # here: a robot process never makes a run id (secrets loads libcrypto)

    return time.strftime("%Y%m%dT%H%M%S", time.gmtime(now)) + "-" + secrets.token_hex(3)


def robot_config(scn: Scenario, i: int, lockstep: bool, run: str = "", digest_: str = "") -> Config:
    """Robot i's slice of the scenario, with the run it belongs to (raises ScenarioError for an id
    outside the scenario)."""
    c = scn.control
    arena: dict[str, Any] = {} if scn.bounds is None else dict(zip(("xmin", "xmax", "ymin", "ymax"),
                                                                   map(float, scn.bounds)), arena=True)
    return replace(scn.robot_config(i, lockstep=lockstep), robots=scn.n, v_max=float(c.v_max or 0.0),
                   w_max=float(c.w_max or 0.0), run=run, digest=digest_, **arena)


def first_difference(mine: str, theirs: str) -> str | None:
    """The first key (in document order) whose value differs between two scenario TOML texts, as
    "key: A here, B in the run"; None when they are equal."""
    try:
        a, b = tomllib.loads(mine), tomllib.loads(theirs)
    except tomllib.TOMLDecodeError as e:
        return f"the run's scenario is not readable TOML ({e})"
    return _diff(a, b, "")


def _show(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 48 else s[:45] + "..."


def _diff(a: Any, b: Any, path: str) -> str | None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in list(a) + [k for k in b if k not in a]:
            where = f"{path}.{k}" if path else k
            if k not in b:
                return f"{where}: {_show(a[k])} here, absent in the run"
            if k not in a:
                return f"{where}: absent here, {_show(b[k])} in the run"
            found = _diff(a[k], b[k], where)
            if found:
                return found
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path}: {len(a)} entries here, {len(b)} in the run"
        for n, (x, y) in enumerate(zip(a, b)):
            found = _diff(x, y, f"{path}[{n}]")
            if found:
                return found
        return None
    return None if a == b else f"{path}: {_show(a)} here, {_show(b)} in the run"


def faults_of(text: str, robots: int, where: str) -> Faults | None:
    """The faults of a run's scenario, from its canonical TOML (Run.scenario); None when it has none.
    Raises ScenarioError (where, key, reason) for a table that does not check (a hostile run message)."""
    import tomllib

    from swarm.core.errors import ScenarioError

    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(where, "", f"not TOML: {e}") from None
    table = doc.get("faults")
    if table is None:
        return None
    from swarm.core import faults as fl  # numpy: only a robot of a run with faults needs it (~8 MiB)
    run = cast("dict[str, Any]", doc.get("run")) if isinstance(doc.get("run"), dict) else {}
    duration, seed = run.get("duration"), run.get("seed", 0)
    if not isinstance(duration, (int, float)) or isinstance(duration, bool) or not isinstance(seed, int):
        raise ScenarioError(where, "run", "needs a number duration and an integer seed")
    f = fl.parse_faults(table, where, robots, float(duration), seed)
    return f if f else None

"""The zenoh key space of docs/protocol.md: the one place that builds and parses keys.

    keys.robot_cmd("default", 7)   -> "swarm/default/robot/7/cmd"
    keys.parse("swarm/default/cell/-3/2/7") -> Key(fleet="default", kind="cell", id=7, cx=-3, cy=2)
    keys.parse("anything else")   -> None

Cells: cx = floor(x / side), cy = floor(y / side), decimal ints (negative allowed).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from swarm.core.errors import SwarmError

PREFIX = "swarm"
ROLES = ("router", "world", "leader", "robot", "viz", "recorder", "launcher")
_FLEET = re.compile(r"^[A-Za-z0-9_\-]{1,64}$")
_INT = re.compile(r"^(0|[1-9][0-9]{0,9})$")
_SIGNED = re.compile(r"^(0|-?[1-9][0-9]{0,9})$")


class KeyError_(SwarmError, ValueError):
    """A fleet name or id that cannot be put in a key."""


def check_fleet(fleet: str) -> str:
    if not isinstance(fleet, str) or not _FLEET.match(fleet):
        raise KeyError_(f"fleet name must be 1-64 characters of letters, digits, '_' or '-', got {fleet!r}")
    return fleet


def _id(i: int) -> int:
    if isinstance(i, bool) or not isinstance(i, int) or i < 0:
        raise KeyError_(f"an id must be an int >= 0, got {i!r}")
    return i


def base(fleet: str) -> str:
    return f"{PREFIX}/{check_fleet(fleet)}"


def leader_ref(fleet: str) -> str:
    return f"{base(fleet)}/leader/ref"


def robot_pose(fleet: str, i: int) -> str:
    return f"{base(fleet)}/robot/{_id(i)}/pose"


def robot_cmd(fleet: str, i: int) -> str:
    return f"{base(fleet)}/robot/{_id(i)}/cmd"


def robot_status(fleet: str, i: int) -> str:
    return f"{base(fleet)}/robot/{_id(i)}/status"


def robot_faults(fleet: str, i: int) -> str:
    """Robot i's fault counters (lock-step under faults: what its fault layer lost or delayed)."""
    return f"{base(fleet)}/robot/{_id(i)}/faults"


def cell(fleet: str, cx: int, cy: int, i: int) -> str:
    return f"{base(fleet)}/cell/{int(cx)}/{int(cy)}/{_id(i)}"


def cell_any(fleet: str, cx: int, cy: int) -> str:
    """Key expression for every robot's state in cell (cx, cy)."""
    return f"{base(fleet)}/cell/{int(cx)}/{int(cy)}/*"


def cell_all(fleet: str) -> str:
    """Key expression for every robot's state in every cell (the world's start barrier)."""
    return f"{base(fleet)}/cell/*/*/*"


def cell_robot_any(fleet: str, i: int) -> str:
    """Key expression for robot i's state in every cell (a real-time robot that lost track of a neighbour)."""
    return f"{base(fleet)}/cell/*/*/{_id(i)}"


def world_obstacles(fleet: str) -> str:
    return f"{base(fleet)}/world/obstacles"


def world_snapshot(fleet: str) -> str:
    return f"{base(fleet)}/world/snapshot"


# Extension keys (beyond the contract's core table in docs/protocol.md; same prefix, same codec).


def world_clock(fleet: str) -> str:
    return f"{base(fleet)}/world/clock"


def world_progress(fleet: str) -> str:
    return f"{base(fleet)}/world/progress"


def world_config(fleet: str, i: int) -> str:
    """The world's configuration queryable for robot i (its slice of the scenario)."""
    return f"{base(fleet)}/world/config/{_id(i)}"


def world_config_any(fleet: str) -> str:
    return f"{base(fleet)}/world/config/*"


def world_run(fleet: str) -> str:
    """The current run's identity (run id, scenario digest): published at each run's start and served."""
    return f"{base(fleet)}/world/run"


def world_bodies(fleet: str) -> str:
    """Static bodies: the final poses of robots that are dead or stopped (world -> every agent)."""
    return f"{base(fleet)}/world/bodies"


def world_events(fleet: str) -> str:
    """Fault and supervision events (world, launcher -> viewers, recorders)."""
    return f"{base(fleet)}/world/events"


def world_claim(fleet: str, claim: str) -> str:
    """The world's queryable that hands a robot started with --id auto its id; `claim` names the
    claimant (a hostname, say) so a restarted robot gets its id back."""
    return f"{base(fleet)}/world/claim/{check_claim(claim)}"


def world_claim_any(fleet: str) -> str:
    return f"{base(fleet)}/world/claim/*"


def estop(fleet: str) -> str:
    """The emergency stop every drive obeys (operator -> drives)."""
    return f"{base(fleet)}/estop"


_CLAIM = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")


def check_claim(claim: str) -> str:
    if not isinstance(claim, str) or not _CLAIM.match(claim):
        raise KeyError_(f"a claim key must be 1-64 characters of letters, digits, '_', '.' or '-', got {claim!r}")
    return claim


def alive(fleet: str, role: str, i: int = 0) -> str:
    if role not in ROLES:
        raise KeyError_(f"role must be one of {', '.join(ROLES)}, got {role!r}")
    return f"{base(fleet)}/alive/{role}/{_id(i)}"


def alive_any(fleet: str, role: str | None = None) -> str:
    return f"{base(fleet)}/alive/{role or '*'}/*"


def proc(fleet: str, role: str, i: int = 0) -> str:
    """A process's own queryable: who it is (protocol.Proc; `swarm ps`). Role and id as in its liveliness token."""
    if role not in ROLES:
        raise KeyError_(f"role must be one of {', '.join(ROLES)}, got {role!r}")
    return f"{base(fleet)}/proc/{role}/{_id(i)}"


def proc_any(fleet: str) -> str:
    return f"{base(fleet)}/proc/*/*"


def robot_any(fleet: str, what: str) -> str:
    """Key expression for one kind of per-robot key of every robot, e.g. robot_any(f, "cmd")."""
    return f"{base(fleet)}/robot/*/{what}"


def cell_of(x: float, y: float, side: float) -> tuple[int, int]:
    return int(math.floor(x / side)), int(math.floor(y / side))


def lockstep_step_bound(reach: float, side: float) -> float:
    """L [m], the largest step a tick the lock-step wait rule assumes (docs/runtime.md)."""
    return (side - reach) / 3.0


def lockstep_wait_reach(reach: float, side: float) -> float:
    """An agent waits at tick k for the robots that were this close at k-1: reach + 2L."""
    return reach + 2.0 * lockstep_step_bound(reach, side)


def cell_robot(key: str) -> int | None:
    """The robot id at the end of a cell key (the hot path of a robot's state messages; `parse`
    does the full check). None if the last chunk is not an id, or the key is a wildcard expression (a put on
    cell/*/*/5 reaches every cell subscription of every robot: it is no robot's state)."""
    if "*" in key or "$" in key:
        return None
    _, _, last = key.rpartition("/")
    if last.isascii() and last.isdigit() and len(last) <= 10 and (last == "0" or last[0] != "0"):
        return int(last)
    return None


@dataclass(frozen=True)
class Key:
    fleet: str
    kind: str  # "ref", "pose", "cmd", "status", "cell", "obstacles", "snapshot", "alive", "clock", "progress",
    #            "config", "run", "bodies", "events", "estop", "claim", "proc"
    id: int | None = None
    cx: int | None = None
    cy: int | None = None
    role: str | None = None
    claim: str | None = None


def parse(key: str) -> Key | None:
    """The parts of a swarm key, or None if it is not one (never raises)."""
    if not isinstance(key, str):
        return None
    p = key.split("/")
    if len(p) < 3 or p[0] != PREFIX or not _FLEET.match(p[1]):
        return None
    fleet, rest = p[1], p[2:]
    if rest == ["leader", "ref"]:
        return Key(fleet, "ref")
    if rest == ["world", "obstacles"]:
        return Key(fleet, "obstacles")
    if rest == ["world", "snapshot"]:
        return Key(fleet, "snapshot")
    if rest == ["world", "clock"]:
        return Key(fleet, "clock")
    if rest == ["world", "progress"]:
        return Key(fleet, "progress")
    if rest == ["world", "run"]:
        return Key(fleet, "run")
    if rest == ["world", "bodies"]:
        return Key(fleet, "bodies")
    if rest == ["world", "events"]:
        return Key(fleet, "events")
    if rest == ["estop"]:
        return Key(fleet, "estop")
    if len(rest) == 3 and rest[:2] == ["world", "claim"] and _CLAIM.match(rest[2]):
        return Key(fleet, "claim", claim=rest[2])
    if len(rest) == 3 and rest[:2] == ["world", "config"] and _INT.match(rest[2]):
        return Key(fleet, "config", id=int(rest[2]))
    if len(rest) == 3 and rest[0] == "robot" and _INT.match(rest[1]) and rest[2] in ("pose", "cmd", "status", "faults"):
        return Key(fleet, rest[2], id=int(rest[1]))
    if len(rest) == 4 and rest[0] == "cell" and _SIGNED.match(rest[1]) and _SIGNED.match(rest[2]) \
            and _INT.match(rest[3]):
        return Key(fleet, "cell", id=int(rest[3]), cx=int(rest[1]), cy=int(rest[2]))
    if len(rest) == 3 and rest[0] == "alive" and rest[1] in ROLES and _INT.match(rest[2]):
        return Key(fleet, "alive", id=int(rest[2]), role=rest[1])
    if len(rest) == 3 and rest[0] == "proc" and rest[1] in ROLES and _INT.match(rest[2]):
        return Key(fleet, "proc", id=int(rest[2]), role=rest[1])
    return None

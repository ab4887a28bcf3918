"""Who may do what on which key: the one role table the router's access control is generated from.

    TABLE["robot_cmd"]                  -> Row(put=(("robot", OWN),), subscribe=(("world", ALL), ...))
    grants("f", "robot", 3).put         -> ("swarm/f/cell/*/*/3", "swarm/f/robot/3/cmd", "swarm/f/robot/3/status")
    grants("f", "world").serve          -> ("swarm/f/world/claim/*", "swarm/f/world/config/*", ...)
    identities(7)                       -> (("router", 0), ("launcher", 0), ..., ("robot", 0), ..., ("robot", 6))

Every key builder of swarm.proto.keys has a row (tests/security holds that): the roles that may
put it, subscribe to it, serve it (a queryable), query it, declare it as a liveliness token, or
watch it (a liveliness subscriber). A grant is (role, scope): OWN is the identity's own id (robot i
puts robot/i/cmd and no other robot's), ALL every id. A builder that only builds wildcard
expressions (cell_any, robot_any, ...) is an alias: its rights are those of the rows it names, at
ALL. The key expressions are made by the builders themselves (`expression`), so this module holds
no key literal and a new key cannot slip past the access control: without a row, the test fails;
with one, the generated ACL covers it.

Roles (one certificate each; robots one per id): router (routes only; its own session sits inside
the router, where no rule applies), launcher (`swarm up` itself, which also runs the recorder, so
it has the recorder's rights), world, leader, robot, viz (the viewer), recorder, operator (a
human's tools: the emergency stop, read-only watching). Pure: no zenoh, no I/O.

Keys outside the swarm/ prefix (a ROS 2 drive's topics) are granted per robot at `swarm secure
init` time: `extra` templates in which "{id}" stands for the robot's id, each granted to that robot
for every action (see `grants`).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field

from swarm.proto import keys

OWN, ALL = "own", "all"
ROLES = ("router", "launcher", "world", "leader", "robot", "viz", "recorder", "operator")
ACTIONS = ("put", "subscribe", "serve", "query", "token", "watch")
INHERITS = {"launcher": ("recorder",)}  # the launcher runs the recorder in its own process

Grant = tuple[str, str]  # (role, OWN | ALL)


@dataclass(frozen=True)
class Row:
    """The roles that may act on one key builder's keys (each action: a tuple of (role, scope))."""

    put: tuple[Grant, ...] = ()
    subscribe: tuple[Grant, ...] = ()
    serve: tuple[Grant, ...] = ()
    query: tuple[Grant, ...] = ()
    token: tuple[Grant, ...] = ()
    watch: tuple[Grant, ...] = ()
    alias_of: tuple[str, ...] = field(default=())  # a wildcard builder: the rows whose keys it matches

    def grants(self, action: str) -> tuple[Grant, ...]:
        grants: tuple[Grant, ...] = getattr(self, action)
        return grants


def _all(*roles: str) -> tuple[Grant, ...]:
    return tuple((r, ALL) for r in roles)


def _own(*roles: str) -> tuple[Grant, ...]:
    return tuple((r, OWN) for r in roles)


READERS = ("viz", "recorder", "operator")  # watch the run: snapshot, progress, events, statuses

TABLE: dict[str, Row] = {
    # the leader's reference: the leader alone puts it
    "leader_ref": Row(put=_all("leader"), subscribe=_all("robot", "viz", "recorder", "operator")),
    # per robot: the world moves robot i (pose), robot i commands itself and reports
    "robot_pose": Row(put=_all("world"), subscribe=_own("robot") + _all("operator")),
    "robot_cmd": Row(put=_own("robot"), subscribe=_all("world", "recorder", "operator")),
    "robot_status": Row(put=_own("robot"), subscribe=_all("world", *READERS)),
    "robot_faults": Row(put=_own("robot"), subscribe=_all("world", *READERS)),
    # a robot's state on its cell key: only robot i puts .../cell/*/*/i
    "cell": Row(put=_own("robot"), subscribe=_all("robot", "world", "operator")),
    "cell_any": Row(alias_of=("cell",)),
    "cell_all": Row(alias_of=("cell",)),
    "cell_robot_any": Row(alias_of=("cell",)),
    # the world's keys: it alone puts or serves them
    "world_obstacles": Row(serve=_all("world"), query=_all("robot", *READERS)),
    "world_snapshot": Row(put=_all("world"), subscribe=_all(*READERS)),
    "world_clock": Row(put=_all("world"), subscribe=_all("robot", "leader", "launcher", "operator")),
    "world_progress": Row(put=_all("world"), subscribe=_all("launcher", *READERS)),
    "world_config": Row(serve=_all("world"), query=_own("robot") + _all(*READERS)),
    "world_config_any": Row(alias_of=("world_config",)),
    # the current run: announced (put) and served; robots and the leader follow it
    "world_run": Row(put=_all("world"), serve=_all("world"), subscribe=_all("robot", "leader"),
                     query=_all("robot", "leader")),
    "world_bodies": Row(put=_all("world"), subscribe=_all("robot", "operator")),
    "world_events": Row(put=_all("world", "launcher"), subscribe=_all("launcher", *READERS)),
    "world_claim": Row(serve=_all("world"), query=_all("robot")),
    "world_claim_any": Row(alias_of=("world_claim",)),
    # the emergency stop: a human's operator tools put it, every robot's drive obeys it
    "estop": Row(put=_all("operator"), subscribe=_all("robot", "world", "operator")),
    # presence: each process declares its own token (keys.alive(fleet, role, id)); some watch them all
    "alive": Row(token=_own("router", "launcher", "world", "leader", "robot", "viz", "recorder"),
                 watch=_all("world", "leader", "robot", "launcher", "operator")),
    "alive_any": Row(alias_of=("alive",)),
    # who a process is (`swarm ps`): each serves its own, the operator's tools ask
    "proc": Row(serve=_own("router", "launcher", "world", "leader", "robot", "viz", "recorder"),
                query=_all("operator", "launcher")),
    "proc_any": Row(alias_of=("proc",)),
    "robot_any": Row(alias_of=("robot_pose", "robot_cmd", "robot_status", "robot_faults")),
}


# --------------------------------------------------------------------------- key expressions

_SAMPLES = {"int": (0, 1), "claim": ("a", "b"), "role": keys.ROLES[:2]}  # two values of each variable parameter


def expression(builder: str, fleet: str, role: str | None = None, own: int | None = None) -> str:
    """The key expression of every key `builder` makes in `fleet`: each variable chunk is `*`, except
    the id (the builder's parameter `i`), which is `own` when given, and the role chunk of an alive
    key, which is `role` when given.

    expression("cell", "f") -> "swarm/f/cell/*/*/*"; expression("cell", "f", own=3) -> "swarm/f/cell/*/*/3";
    expression("alive", "f", "robot", 3) -> "swarm/f/alive/robot/3".
    The builder runs once with every parameter fixed, then once more for each free parameter with
    another value: the chunks that change are that parameter's and become `*`. So the layout stays
    the builder's own, and this module holds no key literal."""
    fn = getattr(keys, builder)
    names, values, free = [], [], []
    for name, p in list(inspect.signature(fn).parameters.items())[1:]:
        if name == "role":
            kind = "role"
        elif name == "claim":
            kind = "claim"
        elif p.annotation in ("int", int):
            kind = "int"
        else:
            raise ValueError(f"{builder}: no rule for a variable parameter {name!r} (teach roles.expression)")
        given = own if name == "i" else role if name == "role" else None
        if given is not None and kind == "role" and given not in keys.ROLES:
            raise ValueError(f"{builder}: the role chunk must be one of {keys.ROLES}, got {given!r}")
        names.append(name)
        values.append(given if given is not None else _SAMPLES[kind][0])
        if given is None:
            free.append((len(values) - 1, _SAMPLES[kind][1]))
    chunks = fn(fleet, *values).split("/")
    for k, other in free:
        varied = fn(fleet, *values[:k], other, *values[k + 1:]).split("/")
        if len(varied) != len(chunks):
            raise ValueError(f"{builder}: parameter {names[k]!r} changes the number of chunks")
        chunks = ["*" if a != b else a for a, b in zip(chunks, varied)]
    return "/".join(chunks)


def identities(robots: int) -> tuple[tuple[str, int], ...]:
    """Every identity of a fleet of `robots` robots: (role, id), id 0 except for robots."""
    if isinstance(robots, bool) or not isinstance(robots, int) or robots < 1:
        raise ValueError(f"robots must be an int >= 1, got {robots!r}")
    return tuple((r, 0) for r in ROLES if r != "robot") + tuple(("robot", i) for i in range(robots))


def common_name(role: str, i: int = 0) -> str:
    """The certificate's common name of an identity: the role, or "robot-<i>"."""
    if role not in ROLES:
        raise ValueError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
    return f"robot-{int(i)}" if role == "robot" else role


def parse_common_name(cn: str) -> tuple[str, int] | None:
    """(role, id) of a common name made by `common_name`, or None."""
    if cn in ROLES and cn != "robot":
        return cn, 0
    head, sep, tail = cn.partition("-")
    if head == "robot" and sep and tail.isascii() and tail.isdigit() and (tail == "0" or tail[0] != "0") \
            and len(tail) <= 10:
        return "robot", int(tail)
    return None


@dataclass(frozen=True)
class Grants:
    """The key expressions one identity may act on, per action (sorted, no duplicates)."""

    put: tuple[str, ...] = ()
    subscribe: tuple[str, ...] = ()
    serve: tuple[str, ...] = ()
    query: tuple[str, ...] = ()
    token: tuple[str, ...] = ()
    watch: tuple[str, ...] = ()
    # the keys it puts, every id: where it may learn of subscribers (so a publisher knows whether
    # anyone listens; robot 3 learns that the world subscribes robot/*/cmd, and may put only robot/3/cmd)
    listeners: tuple[str, ...] = ()
    # the keys it serves, every id: where a query may reach it (a wildcard query, proc/*/*, is in no single
    # robot's own proc/robot/3; it still replies only on its own key)
    askers: tuple[str, ...] = ()

    def of(self, action: str) -> tuple[str, ...]:
        exprs: tuple[str, ...] = getattr(self, action)
        return exprs


def extra_expression(template: str, i: int) -> str:
    """An extra per-robot key expression: `template` with "{id}" replaced by the robot's id."""
    if not isinstance(template, str) or not template or template.startswith("/") or template.endswith("/") \
            or "//" in template:
        raise ValueError(f"an extra key expression must be non-empty chunks separated by '/', got {template!r}")
    return template.replace("{id}", str(int(i)))


def grants(fleet: str, role: str, i: int = 0, extra: tuple[str, ...] = ()) -> Grants:
    """What identity (role, i) may do in `fleet`, from TABLE (plus INHERITS; plus, for a robot, the
    `extra` templates, every action on each)."""
    keys.check_fleet(fleet)
    if role not in ROLES:
        raise ValueError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
    roles = (role, *INHERITS.get(role, ()))
    out: dict[str, set[str]] = {a: set() for a in (*ACTIONS, "listeners", "askers")}
    for builder, row in TABLE.items():
        for action in ACTIONS:
            for r, scope in row.grants(action):
                if r not in roles:
                    continue
                mine = scope == OWN  # the identity's own id, and its own role in an alive key
                out[action].add(expression(builder, fleet, role=r if mine else None, own=i if mine else None))
                if action == "put":
                    out["listeners"].add(expression(builder, fleet))
                elif action == "serve":
                    out["askers"].add(expression(builder, fleet))
    if role == "robot":
        for t in extra:
            e = extra_expression(t, i)
            for action in (*ACTIONS, "listeners", "askers"):
                out[action].add(e)
    return Grants(**{a: tuple(sorted(v)) for a, v in out.items()})


def check_table() -> None:
    """ValueError unless every row names known builders, roles, scopes; OWN only on a builder with
    an id (parameter `i`); aliases only of rows that grant something."""
    for builder, row in TABLE.items():
        fn = getattr(keys, builder, None)
        if not callable(fn):
            raise ValueError(f"row {builder!r}: swarm.proto.keys has no such builder")
        params = inspect.signature(fn).parameters
        for action in ACTIONS:
            for g in row.grants(action):
                if not (isinstance(g, tuple) and len(g) == 2 and g[0] in ROLES and g[1] in (OWN, ALL)):
                    raise ValueError(f"row {builder!r}, {action}: bad grant {g!r}")
                if g[1] == OWN and "i" not in params:
                    raise ValueError(f"row {builder!r}, {action}: OWN on a builder without an id")
        if row.alias_of:
            if any(row.grants(a) for a in ACTIONS):
                raise ValueError(f"row {builder!r}: an alias grants nothing of its own")
            for target in row.alias_of:
                if target not in TABLE or TABLE[target].alias_of:
                    raise ValueError(f"row {builder!r}: alias of {target!r}, which is not a granting row")

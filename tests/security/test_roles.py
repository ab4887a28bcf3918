"""The role table (swarm.proto.roles): every key builder has a row, and the grants say what the issue asks."""

from __future__ import annotations

import inspect

import pytest

from swarm.net.bus import matches
from swarm.proto import keys, roles

pytestmark = pytest.mark.unit

FLEET = "f"
# a sample value per parameter name of a key builder (a builder with another parameter fails the
# test below: give it a sample here and a row in swarm.proto.roles.TABLE)
SAMPLES = {"fleet": FLEET, "i": 3, "cx": -1, "cy": 2, "role": "robot", "claim": "host-1", "what": "cmd"}


def _builders() -> dict[str, str]:
    """Every public function of swarm.proto.keys that makes a key or key expression under the fleet's
    prefix, with a sample of what it makes."""
    out = {}
    for name, fn in inspect.getmembers(keys, inspect.isfunction):
        if name.startswith("_") or fn.__module__ != keys.__name__:
            continue
        params = list(inspect.signature(fn).parameters)
        if not params or params[0] != "fleet":
            continue
        missing = [p for p in params if p not in SAMPLES]
        assert not missing, f"keys.{name}: no sample for parameter(s) {missing}; add them to SAMPLES"
        made = fn(*[SAMPLES[p] for p in params])
        if isinstance(made, str) and made.startswith(keys.base(FLEET) + "/"):
            out[name] = made
    return out


BUILDERS = _builders()


def test_the_introspection_finds_the_builders():
    assert {"leader_ref", "robot_pose", "robot_cmd", "robot_status", "cell", "cell_any", "world_obstacles",
            "world_snapshot", "world_clock", "world_progress", "world_config", "world_config_any", "world_run",
            "world_bodies", "world_events", "world_claim", "world_claim_any", "estop", "alive", "alive_any",
            "robot_any"} <= set(BUILDERS)
    assert "base" not in BUILDERS and "check_fleet" not in BUILDERS and "parse" not in BUILDERS


@pytest.mark.parametrize("builder", sorted(BUILDERS))
def test_every_key_builder_has_a_row(builder):
    assert builder in roles.TABLE, f"keys.{builder} has no row in swarm.proto.roles.TABLE: say who may use it"


def test_every_row_names_a_builder_and_is_well_formed():
    assert set(roles.TABLE) <= set(BUILDERS)
    roles.check_table()


@pytest.mark.parametrize("builder", sorted(b for b, r in roles.TABLE.items() if not r.alias_of))
def test_a_granting_row_is_used(builder):
    row = roles.TABLE[builder]
    assert any(row.grants(a) for a in roles.ACTIONS), f"row {builder} grants nothing"


@pytest.mark.parametrize("builder", sorted(b for b, r in roles.TABLE.items() if r.alias_of))
def test_a_wildcard_builder_matches_only_keys_of_the_rows_it_aliases(builder):
    """cell_any(f, -1, 2) is inside cell's expression; robot_any(f, "cmd") inside robot_cmd's, etc."""
    made = BUILDERS[builder]
    targets = [roles.expression(t, FLEET) for t in roles.TABLE[builder].alias_of]
    samples = {"robot_any": [keys.robot_any(FLEET, w) for w in ("pose", "cmd", "status")],
               "alive_any": [keys.alive_any(FLEET), keys.alive_any(FLEET, "robot")]}.get(builder, [made])
    for expr in samples:
        # the expression (its * chunks read as concrete chunks "*") lies within one alias target
        assert any(matches(t, expr) for t in targets), f"{expr} is not within {targets}"


@pytest.mark.parametrize("builder, own, expected", [
    ("cell", None, "swarm/f/cell/*/*/*"),
    ("cell", 3, "swarm/f/cell/*/*/3"),
    ("robot_cmd", 5, "swarm/f/robot/5/cmd"),
    ("robot_pose", None, "swarm/f/robot/*/pose"),
    ("world_config", None, "swarm/f/world/config/*"),
    ("world_claim", None, "swarm/f/world/claim/*"),
    ("leader_ref", 3, "swarm/f/leader/ref"),
    ("alive", None, "swarm/f/alive/*/*"),
])
def test_expressions_are_made_by_the_builders(builder, own, expected):
    assert roles.expression(builder, FLEET, own=own) == expected
    assert roles.expression("alive", FLEET, role="world", own=0) == keys.alive(FLEET, "world")


def test_robot_i_puts_only_its_own_keys():
    g = roles.grants(FLEET, "robot", 3)
    assert g.put == tuple(sorted((keys.robot_cmd(FLEET, 3), keys.robot_status(FLEET, 3), keys.robot_faults(FLEET, 3),
                                  "swarm/f/cell/*/*/3")))
    assert g.token == (keys.alive(FLEET, "robot", 3),)
    assert g.serve == (keys.proc(FLEET, "robot", 3),)  # who it is (swarm ps), and nothing else
    assert keys.world_config(FLEET, 3) in g.query and keys.world_config(FLEET, 5) not in g.query
    assert keys.robot_pose(FLEET, 3) in g.subscribe and keys.robot_pose(FLEET, 5) not in g.subscribe
    assert keys.leader_ref(FLEET) in g.subscribe and keys.estop(FLEET) in g.subscribe


@pytest.mark.parametrize("role, puts", [
    ("leader", {keys.leader_ref(FLEET)}),
    ("world", {"swarm/f/robot/*/pose", keys.world_snapshot(FLEET), keys.world_clock(FLEET), keys.world_progress(FLEET),
               keys.world_run(FLEET), keys.world_bodies(FLEET), keys.world_events(FLEET)}),
    ("operator", {keys.estop(FLEET)}),
    ("launcher", {keys.world_events(FLEET)}),
    ("viz", set()), ("recorder", set()), ("router", set()),
])
def test_what_each_role_may_put(role, puts):
    assert set(roles.grants(FLEET, role).put) == puts


def test_only_the_world_serves_besides_each_process_saying_who_it_is():
    for role, i in roles.identities(4):
        served = set(roles.grants(FLEET, role, i).serve)
        assert role == "operator" and not served or keys.proc(FLEET, role, i) in served, (role, i, served)
        served = {k for k in served if not k.startswith(f"swarm/{FLEET}/proc/")}  # the launcher: the recorder's too
        assert bool(served) == (role == "world"), (role, i, served)
    assert set(roles.grants(FLEET, "world").serve) == {
        keys.world_obstacles(FLEET), "swarm/f/world/config/*", keys.world_run(FLEET), "swarm/f/world/claim/*",
        keys.proc(FLEET, "world", 0)}
    assert roles.grants(FLEET, "operator").serve == () and keys.proc_any(FLEET) in roles.grants(FLEET, "operator").query


def test_the_launcher_has_the_recorders_rights():
    launcher, recorder = roles.grants(FLEET, "launcher"), roles.grants(FLEET, "recorder")
    for action in roles.ACTIONS:
        assert set(recorder.of(action)) - {keys.alive(FLEET, "recorder")} <= set(launcher.of(action)), action


def test_a_publisher_learns_of_the_subscribers_of_every_id():
    """Robot 3 puts robot/3/cmd and is told of the world's robot/*/cmd subscription (so zenoh's
    matching status, bus.wanted(), is true), but may put no other robot's."""
    g = roles.grants(FLEET, "robot", 3)
    assert set(g.listeners) == {"swarm/f/robot/*/cmd", "swarm/f/robot/*/status", "swarm/f/robot/*/faults",
                                "swarm/f/cell/*/*/*"}


def test_extra_robot_keys_are_per_robot():
    g = roles.grants(FLEET, "robot", 4, extra=("robot{id}/cmd_vel", "robot{id}/odom"))
    for action in roles.ACTIONS:
        assert {"robot4/cmd_vel", "robot4/odom"} <= set(g.of(action))
    assert "robot4/cmd_vel" not in roles.grants(FLEET, "world", 0, extra=("robot{id}/cmd_vel",)).put
    with pytest.raises(ValueError):
        roles.extra_expression("/rooted/{id}", 1)


@pytest.mark.parametrize("role, i, cn", [("robot", 0, "robot-0"), ("robot", 12, "robot-12"), ("world", 0, "world"),
                                         ("viz", 0, "viz"), ("operator", 0, "operator")])
def test_common_names_round_trip(role, i, cn):
    assert roles.common_name(role, i) == cn
    assert roles.parse_common_name(cn) == (role, i)


@pytest.mark.parametrize("cn", ["robot", "robot-", "robot-01", "robot--1", "robot-x", "ghost", "", "robot-12345678901"])
def test_bad_common_names_parse_to_none(cn):
    assert roles.parse_common_name(cn) is None


def test_identities_are_every_role_and_every_robot():
    ids = roles.identities(3)
    assert ids[-3:] == (("robot", 0), ("robot", 1), ("robot", 2))
    assert {r for r, _ in ids} == set(roles.ROLES)
    with pytest.raises(ValueError):
        roles.identities(0)

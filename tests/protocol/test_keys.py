"""The key grammar of docs/protocol.md."""

import pytest

from swarm.proto import keys

pytestmark = pytest.mark.unit


@pytest.mark.parametrize(
    "key, expected",
    [
        (keys.leader_ref("f1"), keys.Key("f1", "ref")),
        (keys.robot_pose("f1", 7), keys.Key("f1", "pose", id=7)),
        (keys.robot_cmd("default", 0), keys.Key("default", "cmd", id=0)),
        (keys.robot_status("a-b_c", 12), keys.Key("a-b_c", "status", id=12)),
        (keys.cell("f", -3, 2, 5), keys.Key("f", "cell", id=5, cx=-3, cy=2)),
        (keys.cell("f", 0, -1, 0), keys.Key("f", "cell", id=0, cx=0, cy=-1)),
        (keys.world_obstacles("f"), keys.Key("f", "obstacles")),
        (keys.world_snapshot("f"), keys.Key("f", "snapshot")),
        (keys.alive("f", "robot", 3), keys.Key("f", "alive", id=3, role="robot")),
    ],
)
def test_build_then_parse(key, expected):
    assert keys.parse(key) == expected


def test_literal_layout():
    assert keys.robot_cmd("default", 7) == "swarm/default/robot/7/cmd"
    assert keys.cell("default", -3, 2, 7) == "swarm/default/cell/-3/2/7"
    assert keys.alive("default", "world") == "swarm/default/alive/world/0"
    assert keys.cell_any("f", 1, 2) == "swarm/f/cell/1/2/*"


@pytest.mark.parametrize(
    "key",
    ["", "swarm", "swarm/f", "other/f/leader/ref", "swarm/f/leader", "swarm/f/robot/x/pose", "swarm/f/robot/-1/pose",
     "swarm/f/robot/07/pose", "swarm/f/robot/1/teleport", "swarm/f/cell/1/2", "swarm/f/cell/a/2/3",
     "swarm/f/cell/1/2/-3", "swarm/f/cell/-0/2/3", "swarm/f/alive/ghost/1", "swarm/f*/leader/ref",
     "swarm/f/robot/1/pose/extra", "swarm/f/robot/99999999999/pose", None, 42],
)
def test_malformed_keys_parse_to_none(key):
    assert keys.parse(key) is None


@pytest.mark.parametrize("fleet", ["", "a/b", "a*", "x" * 65, "sp ace", "$", None])
def test_bad_fleet_names_are_refused(fleet):
    with pytest.raises(keys.KeyError_):
        keys.leader_ref(fleet)


@pytest.mark.parametrize("bad", [-1, 1.5, True, "3"])
def test_bad_ids_are_refused(bad):
    with pytest.raises(keys.KeyError_):
        keys.robot_cmd("f", bad)


def test_cell_of_floors_negative_coordinates():
    assert keys.cell_of(-0.1, 0.1, 1.5) == (-1, 0)
    assert keys.cell_of(3.0, -3.0, 1.5) == (2, -2)


@pytest.mark.parametrize("last", ["0", "7", "123", "9999999999", "-3", "07", "x", "", "²", "1.5", "99999999999", "1 "])
def test_cell_robot_agrees_with_parse(last):
    """The hot-path id of a cell key is the id `parse` finds, or None where `parse` refuses the key."""
    key = f"swarm/f/cell/1/-2/{last}"
    full = keys.parse(key)
    assert keys.cell_robot(key) == (full.id if full is not None else None)


@pytest.mark.parametrize("key", ["swarm/f/cell/*/*/5", "swarm/*/cell/1/2/5", "swarm/f/cell/**/5", "swarm/f/cell/$*1/2/5",
                                 "**/5"])
def test_a_wildcard_cell_key_names_no_robot(key):
    """A put on a key expression with wildcards reaches every subscription it intersects: no robot's state."""
    assert keys.cell_robot(key) is None and keys.parse(key) is None

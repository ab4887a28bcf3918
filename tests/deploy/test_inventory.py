"""The inventory (swarm.core.inventory): every refusal names the file, the key and the reason; the
inventory applied to a scenario (starts, limits only tightened); the pre-flight's static checks, each
naming the robot and the reason; and the `swarm preflight` command's static failures (exit 1)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from swarm.core import inventory, scenario_file
from swarm.core.inventory import InventoryError
from swarm.core.scenario import ScenarioError
from tests.conftest import toml_text

pytestmark = pytest.mark.unit

TB3 = scenario_file.load("turtlebot3", progress=scenario_file.silent)


def rows(n: int = 7, **extra) -> dict:
    return {"fleet": "lab", "robot": [{"id": i, **extra} for i in range(n)]}


def write(tmp_path: Path, doc: dict | str, name: str = "fleet.toml") -> str:
    p = tmp_path / name
    p.write_text(doc if isinstance(doc, str) else toml_text(doc))
    return str(p)


def test_defaults_and_a_full_row(tmp_path):
    doc = rows(7)
    doc["robot"][3] = {"id": 3, "drive": "ros2", "flavor": "bridge", "namespace": "/tb3_3/", "domain": 7,
                       "twist": "stamped", "connect": "tcp/192.168.1.23:7447", "initial_pose": [1.0, -2.0, 0.5],
                       "v_max": 0.2, "w_max": 2.0, "cmd_timeout": 0.5}
    inv = inventory.load(write(tmp_path, doc))
    assert inv.fleet == "lab" and [e.id for e in inv.robots] == list(range(7))
    e0 = inv.entry(0)
    assert (e0.drive, e0.flavor, e0.namespace, e0.domain, e0.twist, e0.connect, e0.initial_pose) == \
        ("ros2", "rmw_zenoh", "robot0", 0, "plain", None, None)
    e3 = inv.entry(3)
    assert (e3.flavor, e3.namespace, e3.domain, e3.twist, e3.connect, e3.initial_pose, e3.v_max, e3.w_max) == \
        ("bridge", "tb3_3", 7, "stamped", "tcp/192.168.1.23:7447", (1.0, -2.0, 0.5), 0.2, 2.0)
    assert e3.cmd_timeout == 0.5 and e0.cmd_timeout is None
    assert inv.endpoints == ("tcp/192.168.1.23:7447",)
    with pytest.raises(InventoryError, match="has no robot 9"):
        inv.entry(9)


@pytest.mark.parametrize("edit, key, reason", [
    (lambda d: d.update(extra=1), "extra", "unknown key"),
    (lambda d: d.pop("robot"), "robot", "missing required key"),
    (lambda d: d.update(fleet="a b"), "fleet", "1-64 characters"),
    (lambda d: d["robot"][1].update(colour="red"), "robot[1].colour", "unknown key"),
    (lambda d: d["robot"][1].pop("id"), "robot[1].id", "missing required key"),
    (lambda d: d["robot"][1].update(id=-1), "robot[1].id", "must be >= 0"),
    (lambda d: d["robot"][1].update(id=0), "robot[1].id", "robot 0 is listed twice"),
    (lambda d: d["robot"][1].update(drive="sim"), "robot[1].drive", "must be one of 'ros2'"),
    (lambda d: d["robot"][1].update(flavor="dds"), "robot[1].flavor", "must be one of"),
    (lambda d: d["robot"][1].update(twist="fast"), "robot[1].twist", "must be one of"),
    (lambda d: d["robot"][1].update(namespace="1robot"), "robot[1].namespace", "ROS namespace"),
    (lambda d: d["robot"][1].update(namespace="robot0"), "robot[1].namespace", "also robot[0]'s"),
    (lambda d: d["robot"][1].update(domain=300), "robot[1].domain", "0..232"),
    (lambda d: d["robot"][1].update(connect="192.168.1.2"), "robot[1].connect", "zenoh endpoint"),
    (lambda d: d["robot"][1].update(connect="tcp/host:70000"), "robot[1].connect", "zenoh endpoint"),
    (lambda d: d["robot"][1].update(initial_pose=[1.0, 2.0]), "robot[1].initial_pose", "list of 3 numbers"),
    (lambda d: d["robot"][1].update(initial_pose=[1.0, math.nan, 0.0]), "robot[1].initial_pose[1]", "finite"),
    (lambda d: d["robot"][1].update(v_max=0.0), "robot[1].v_max", "must be > 0"),
    (lambda d: d["robot"][1].update(w_max=True), "robot[1].w_max", "must be a number"),
    (lambda d: d["robot"][1].update(cmd_timeout=0), "robot[1].cmd_timeout", "must be > 0"),
    (lambda d: d["robot"][1].update(cmd_timeout=90), "robot[1].cmd_timeout", "at most 60 s"),
])
def test_every_refusal_names_the_file_the_key_and_the_reason(tmp_path, edit, key, reason):
    doc = rows(3)
    edit(doc)
    path = write(tmp_path, doc)
    with pytest.raises(InventoryError) as e:
        inventory.load(path)
    assert (e.value.where, e.value.key) == (path, key) and reason in e.value.reason, str(e.value)


def test_unreadable_files(tmp_path):
    with pytest.raises(InventoryError, match="no such file"):
        inventory.load(tmp_path / "none.toml")
    with pytest.raises(InventoryError, match="not valid TOML"):
        inventory.load(write(tmp_path, "fleet = [\n"))
    with pytest.raises(InventoryError, match="one or more"):
        inventory.load(write(tmp_path, "robot = 3\n"))
    assert issubclass(InventoryError, ScenarioError)  # exit 2 like any bad scenario


def test_apply_starts_limits_and_precedence(tmp_path):
    doc = rows(7, v_max=0.2)
    doc["robot"][2]["initial_pose"] = [3.0, -4.0, 1.0]
    doc["robot"][4]["initial_pose"] = [5.0, -5.0, 0.0]
    doc["robot"][5]["w_max"] = 1.5
    inv = inventory.load(write(tmp_path, doc))
    fleet = inventory.apply(inv, TB3, poses={4: (6.0, -6.0, 0.25)})
    assert fleet.given is TB3 and fleet.scenario.name == TB3.name
    np.testing.assert_array_equal(fleet.scenario.poses[2], [3.0, -4.0, 1.0])
    np.testing.assert_array_equal(fleet.scenario.poses[4], [6.0, -6.0, 0.25])  # the flag beats the inventory
    np.testing.assert_array_equal(fleet.scenario.poses[0], TB3.poses[0])
    assert fleet.robots[4].start_from == "--initial-pose" and "robot[2].initial_pose" in fleet.robots[2].start_from
    assert fleet.robots[0].start_from == "the scenario"
    again = scenario_file.load("turtlebot3", progress=scenario_file.silent)
    np.testing.assert_array_equal(TB3.poses[2], again.poses[2])  # the scenario given is not changed
    assert fleet.limits(0) == (0.2, 2.84) and fleet.limits(5) == (0.2, 1.5)
    assert "inventory" in fleet.robots[0].v_from and "scenario" in fleet.robots[0].w_from
    assert fleet.scenario.control.v_max == 0.22  # the scenario's own limit stays; each robot's is in the fleet


def test_apply_refuses_a_looser_limit_and_other_robots(tmp_path):
    doc = rows(7)
    doc["robot"][6]["v_max"] = 0.3
    path = write(tmp_path, doc)
    with pytest.raises(InventoryError) as e:
        inventory.apply(inventory.load(path), TB3)
    assert e.value.key == "robot[6].v_max" and "would loosen the scenario's control.v_max = 0.22" in e.value.reason
    with pytest.raises(InventoryError, match=r"has no robot 5, 6 \(give --robots 5"):
        inventory.apply(inventory.load(write(tmp_path, rows(5), "five.toml")), TB3)
    with pytest.raises(InventoryError, match="robot 7 is not in scenario"):
        inventory.apply(inventory.load(write(tmp_path, rows(8), "eight.toml")), TB3)
    with pytest.raises(ScenarioError, match="robot 9 is not in the scenario"):
        inventory.apply(inventory.load(write(tmp_path, rows(7), "seven.toml")), TB3, poses={9: (0.0, 0.0, 0.0)})


def _problems(tmp_path, doc, scn=TB3, **kw):
    fleet = inventory.apply(inventory.load(write(tmp_path, doc)), scn, **kw)
    return [str(p) for p in inventory.static_problems(fleet)]


def test_a_good_fleet_has_no_static_problem(tmp_path):
    assert _problems(tmp_path, rows(7)) == []


def test_static_refusals_name_the_robot_and_the_reason(tmp_path):
    doc = rows(7)
    x, y, _ = TB3.poses[3]
    doc["robot"][2]["initial_pose"] = [float(x) + 0.1, float(y), 0.0]  # inside r = 0.22 of robot 3
    doc["robot"][5]["v_max"] = 0.15  # 0.8 x 0.15 = 0.12 < the leader's 0.15 m/s
    doc["robot"][6]["v_max"] = 0.01  # below control.vt = 0.02, and the segment
    ob = TB3.obstacles[0]
    probs = _problems(tmp_path, doc, poses={0: (float(ob[0]) + 0.05, float(ob[1]), 0.0)})
    assert any(p.startswith("robot 0: starts 0.05 m from obstacle 0") and "inside its r = 0.15" in p for p in probs)
    assert any(p.startswith("robot 2: starts 0.1 m from robot 3, closer than r = 0.22 m") for p in probs)
    assert any(p.startswith("robot 3: starts 0.1 m from robot 2") for p in probs)
    assert any(p.startswith("robot 5: leader.segments[0] moves at |v| = 0.15 m/s, more than 0.8 x v_max = 0.12")
               and "robot[5].v_max" in p for p in probs)
    assert any(p.startswith("robot 6: v_max = 0.01 m/s") and "below control.vt = 0.02" in p for p in probs)
    assert [int(p.split()[1].rstrip(":")) for p in probs] == sorted(int(p.split()[1].rstrip(":")) for p in probs)


def test_static_refusals_of_the_scenario_itself(tmp_path, write_scenario, base_doc):
    """A turn over 0.8 w_max, a start outside the arena, no limit at all: each names the robot."""
    base_doc["control"].update(v_max=1.0, w_max=0.5)
    base_doc["leader"]["segments"] = [{"duration": 10.0, "v": 0.5, "w": 0.45}]
    base_doc["arena"] = {"bounds": [-10.0, 10.0, -5.0, 5.0]}
    scn = scenario_file.load(write_scenario(base_doc), progress=scenario_file.silent)
    probs = _problems(tmp_path, {"robot": [{"id": 0}, {"id": 1, "initial_pose": [-11.0, 0.0, 0.0]}]}, scn)
    assert "robot 0: leader.segments[0] turns at |w| = 0.45 rad/s, more than 0.8 x w_max = 0.4 rad/s" in probs[0]
    assert any(p.startswith("robot 1: starts at (-11, 0)") and "outside arena.bounds [-10, 10, -5, 5]" in p
               for p in probs)
    base_doc["control"].pop("v_max")
    scn = scenario_file.load(write_scenario(base_doc, "nolimit.toml"), progress=scenario_file.silent)
    probs = _problems(tmp_path, {"robot": [{"id": 0}, {"id": 1, "v_max": 0.7}]}, scn)
    assert any(p.startswith("robot 0: no v_max") for p in probs)
    assert not any(p.startswith("robot 1: no v_max") for p in probs)


def test_notes_warn_of_a_scenario_without_an_arena(tmp_path):
    fleet = inventory.apply(inventory.load(write(tmp_path, rows(7))), TB3)
    assert any("no arena.bounds" in n for n in inventory.notes(fleet))
    text = inventory.describe(fleet)
    assert "robot 3: ros2 rmw_zenoh /robot3 domain 0 twist plain" in text and "from the scenario" in text


def test_notes_name_the_robots_whose_base_timeout_is_unknown(tmp_path):
    """The safety rule counts a base's own cmd_vel timeout (cmd_timeout) in what a robot whose agent died can still
    reach: the robots without one are named, once."""
    doc = {"robot": [{"id": i, "namespace": f"robot{i}", **({"cmd_timeout": 0.5} if i % 2 else {})} for i in range(7)]}
    fleet = inventory.apply(inventory.load(write(tmp_path, doc)), TB3)
    said = [n for n in inventory.notes(fleet) if "cmd_timeout" in n]
    assert len(said) == 1 and said[0].startswith("no cmd_timeout for robots 0, 2, 4, 6:"), said
    full = {"robot": [{**r, "cmd_timeout": 0.3} for r in doc["robot"]]}
    assert not any("cmd_timeout" in n for n in inventory.notes(inventory.apply(inventory.load(write(tmp_path, full)), TB3)))


def test_an_inventory_row_gives_its_robots_attachment_form(tmp_path):
    doc = {"robot": [{"id": 0, "attachment": "v1"}, {"id": 1}]}
    inv = inventory.load(write(tmp_path, doc))
    assert [e.attachment for e in inv.robots] == ["v1", "auto"]
    with pytest.raises(inventory.InventoryError, match=r"robot\[0\]\.attachment"):
        inventory.load(write(tmp_path, {"robot": [{"id": 0, "attachment": "v3"}]}))


def test_a_burger_fleet_refuses_the_default_scenario_and_passes_it_scaled(tmp_path):
    """TurtleBot3 Burgers (v_max 0.22 m/s, w_max 2.84 rad/s in the inventory) under paper-50hz: the pre-flight refuses
    the leader's segments, naming the speeds; `swarm scenario scale` slows the leader down by k to fit, the same path
    (the leader's pose at t / k is the original's at t), and the pre-flight passes."""
    from swarm.core import kinematics

    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=7), progress=scenario_file.silent)
    doc = {"robot": [{"id": i, "v_max": 0.22, "w_max": 2.84} for i in range(7)]}
    probs = _problems(tmp_path, doc, scn)
    assert probs[0].startswith("robot 0: leader.segments[0] moves at |v| = 0.5 m/s, more than 0.8 x v_max = 0.176 m/s")
    out, k = scenario_file.scaled(scn, 0.22, 2.84)
    assert 0.0 < k < 1.0 and out.duration == pytest.approx(scn.duration / k)
    assert out.control.v_max == 0.22 and out.control.w_max == 2.84
    reach = float(np.max(np.hypot(scn.offsets[:, 0], scn.offsets[:, 1])))
    assert max(abs(g.v) + abs(g.w) * reach for g in out.leader.segments) <= 0.8 * 0.22 + 1e-12
    a, b = scn.leader.table(), out.leader.table()
    for t in np.linspace(0.0, scn.duration, 37):
        assert kinematics.leader_state(b, t / k)[:3] == pytest.approx(kinematics.leader_state(a, t)[:3], abs=1e-9)
    again = scenario_file.load(write(tmp_path, scenario_file.to_toml(out), "burger.toml"), progress=scenario_file.silent)
    assert _problems(tmp_path, doc, again) == []
    same, one = scenario_file.scaled(again, 0.22, 2.84)
    assert one == pytest.approx(1.0, abs=1e-9) and same.duration == pytest.approx(again.duration)


def test_a_robot_model_gives_its_limits_and_footprint(tmp_path):
    """model = "burger" (ROBOTIS: 0.22 m/s, 2.84 rad/s, radius 0.105 m): the limits where the row gives none, the
    scenario's where they are tighter, a row's own only if tighter than the model's; a footprint larger than the
    scenario's r allows is a pre-flight problem: two waffles (0.22 m in radius) touch 0.44 m apart, more than
    turtlebot3's r = 0.22 m, and an obstacle of r 0.15 m is smaller than a waffle."""
    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=7), progress=scenario_file.silent)
    doc = {"robot": [{"id": i, "model": "burger"} for i in range(7)]}
    doc["robot"][3]["v_max"] = 0.2
    fleet = inventory.apply(inventory.load(write(tmp_path, doc)), scn)
    assert (fleet.limits(0), fleet.robots[0].v_from) == ((0.22, 2.84), "a burger's (robot[0].model)")
    assert fleet.limits(3) == (0.2, 2.84) and "a burger" in inventory.describe(fleet)
    probs = [str(p) for p in inventory.static_problems(fleet)]
    assert probs[0].startswith("robot 0: leader.segments[0] moves at |v| = 0.5 m/s, more than 0.8 x v_max = 0.176 m/s "
                               "(v_max 0.22 m/s from a burger's (robot[0].model))"), probs
    tb3 = inventory.apply(inventory.load(write(tmp_path, doc)), TB3)  # the scenario's 0.22 and 2.84: as tight
    assert tb3.limits(0) == (0.22, 2.84) and tb3.robots[0].v_from == "the scenario's control.v_max"
    assert inventory.static_problems(tb3) == []  # two Burgers touch 0.21 m apart, within r = 0.22 m
    waffles = inventory.apply(inventory.load(write(tmp_path, {"robot": [{"id": i, "model": "waffle"} for i in range(7)]})),
                              TB3)
    assert waffles.limits(0) == (0.22, 1.82)  # the scenario's v_max, the waffle's w_max
    said = [str(p) for p in inventory.static_problems(waffles)]
    assert "robot 0: two waffles touch with their centres 0.44 m apart (a footprint radius of 0.22 m), more than the " \
        "scenario's bodies.r = 0.22 m, the distance the law keeps robots apart by and the referee counts a collision " \
        "at: give bodies.r >= 0.44" in said, said
    assert any(p.startswith("robot 0: obstacle 0's r = 0.15 m is less than a waffle's footprint radius 0.22 m")
               for p in said), said
    doc["robot"][2]["v_max"] = 0.3
    with pytest.raises(InventoryError, match=r"robot\[2\]\.v_max.*0\.3 m/s is more than a burger can do \(0\.22 m/s\)"):
        inventory.load(write(tmp_path, doc))
    with pytest.raises(InventoryError, match=r"robot\[0\]\.model"):
        inventory.load(write(tmp_path, {"robot": [{"id": 0, "model": "roomba"}]}))

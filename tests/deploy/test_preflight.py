"""The pre-flight's network part (swarm.cli.preflight) against a simulated ROS 2 fleet on the in-memory
bus: fresh odometry passes; a stale, a silent or a missing robot, a cmd_vel of the other type and a
bridge nobody listens to are refused, each naming the robot and the reason; nothing is put on cmd_vel."""

from __future__ import annotations

import threading

import pytest

from swarm.cli import preflight
from swarm.cli.preflight import odometry_verdict
from swarm.core import inventory, scenario_file
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import ros2
from world.ros2_fleet import Ros2Fleet

pytestmark = pytest.mark.timeout(60)
TB3 = scenario_file.load("turtlebot3", progress=scenario_file.silent).replace()


@pytest.mark.unit
@pytest.mark.parametrize("arrivals, verdict", [
    ([], "no odometry"),
    ([9.0 + 0.05 * k for k in range(31)], None),  # 20 Hz through the window
    ([9.0, 9.4, 9.8, 10.2, 10.6], None),  # 2.5 Hz: gaps of 0.4 s
    ([9.0, 9.6, 10.0], "a gap of 0.60 s"),  # a gap inside
    ([9.0 + 0.05 * k for k in range(20)], "a gap of 0.55 s"),  # stopped before the end (last at 9.95)
    ([8.0], "a gap of 2.50 s"),  # one message, long ago
    ([9.7, 10.0, 10.3], "a gap of 0.70 s"),  # nothing for the window's first 0.7 s
])
def test_odometry_verdict(arrivals, verdict):
    got = odometry_verdict(arrivals, (9.0, 10.5), 0.5)
    assert (got is None) if verdict is None else (verdict in got), got


class Fleet:
    """A Ros2Fleet publishing odometry on a thread: each robot at its own rate (0: never)."""

    def __init__(self, net, fleet: inventory.Fleet, rates: dict[int, float], flavor="rmw_zenoh", twist="plain",
                 namespaces=None, tokens=True, attachment="v2"):
        self.bus = MemoryBus(net)
        names = namespaces or {r.id: r.entry.namespace for r in fleet.robots}
        self.ros = Ros2Fleet(self.bus, [tuple(map(float, q)) for q in fleet.scenario.poses], flavor, twist,
                             namespace=lambda i: names[i], attachment=attachment)
        if tokens:  # the robots' side is up (cmd_vel subscribed; rmw_zenoh: the graph's tokens)
            self.ros.start()
        self.fleet, self.rates, self.stop = fleet, rates, threading.Event()
        self.cmds = []
        for key in self.ros.cmd_keys if tokens else ():  # what a robot would get on cmd_vel
            self.bus.subscribe(key, lambda k, b: self.cmds.append(k))
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        import time

        t0 = time.monotonic()
        next_t = {i: 0.0 for i, hz in self.rates.items() if hz > 0}
        while not self.stop.wait(0.005):
            now = time.monotonic() - t0
            for i in list(next_t):
                if now >= next_t[i]:
                    self.ros.publish_odom(i, now, *self.fleet.scenario.poses[i], 0.0, 0.0)
                    next_t[i] = now + 1.0 / self.rates[i]

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2.0)
        self.ros.close()


def fleet_of(n=3, **rows):
    doc = {"robot": [{"id": i, **rows.get(f"r{i}", {})} for i in range(n)]}
    return inventory.apply(inventory.parse(doc, "fleet.toml"), TB3_N[n])


TB3_N = {n: scenario_file.load("turtlebot3", scenario_file.Overrides(robots=n), progress=scenario_file.silent)
         for n in (3,)}


def run_check(fleet, rates, timeout_s=3.0, **kw):
    net = MemoryNet()
    sim = Fleet(net, fleet, rates, **kw)
    try:
        return preflight.check(MemoryBus(net), fleet, timeout_s=timeout_s, window_s=1.0), sim
    finally:
        sim.close()


@pytest.mark.unit
def test_a_good_fleet_passes_and_nothing_is_sent_to_a_robot():
    report, sim = run_check(fleet_of(), {0: 20, 1: 20, 2: 20})
    assert report.ok, report.text()
    assert all(15 <= r <= 25 for r in report.rates.values()), report.rates
    assert sim.cmds == []
    assert report.text().splitlines()[-1] == "pre-flight passed" and "robot 2: ok" in report.text()
    assert report.attachments == {0: "v2", 1: "v2", 2: "v2"} and "rmw_zenoh attachments v2 (rmw_zenoh Rolling 0.6.0" \
        in report.text()


@pytest.mark.unit
def test_the_robots_rmw_zenoh_release_is_named_by_its_attachments():
    report, _ = run_check(fleet_of(), {0: 20, 1: 20, 2: 20}, attachment="v1")
    assert report.ok and report.attachments == {0: "v1", 1: "v1", 2: "v1"}, report.text()
    assert "robot 1: ok" in report.text() and "rmw_zenoh attachments v1 (rmw_zenoh Rolling before 0.6.0, Jazzy " \
        "0.2.0-0.2.3 or Humble 0.1.0-0.1.1)" in report.text()


@pytest.mark.unit
def test_a_stale_and_a_silent_robot_are_refused():
    report, _ = run_check(fleet_of(), {0: 20, 1: 0.4, 2: 0}, timeout_s=2.0)
    text = report.text()
    assert [p.robot for p in report.problems] == [1, 2], text
    assert str(report.problems[0]).startswith("robot 1: odometry is stale:") and "more than the 0.5 s" in text
    assert str(report.problems[1]).startswith("robot 2: no odometry on 0/robot2/odom/nav_msgs::msg::dds_::Odometry_")
    assert text.splitlines()[-1] == "pre-flight FAILED: 2 problems, robots 1, 2; no robot was moved"


@pytest.mark.unit
def test_a_robot_missing_from_the_ros_graph():
    fleet = fleet_of()
    report, _ = run_check(fleet, {0: 20, 1: 20, 2: 20}, timeout_s=1.0,
                          namespaces={0: "robot0", 1: "robot1", 2: "tb3_2"})  # robot 2 came up in another namespace
    probs = [str(p) for p in report.problems]
    assert probs[0].startswith("robot 2: no subscriber of /robot2/cmd_vel in the ROS 2 graph of domain 0")
    assert "nodes seen: /robot0/turtlebot3_node, /robot1/turtlebot3_node, /tb3_2/turtlebot3_node" in probs[0]
    assert probs[1].startswith("robot 2: no publisher of /robot2/odom (nav_msgs/msg/Odometry)")


@pytest.mark.unit
def test_cmd_vel_of_the_other_type_names_the_fix():
    report, _ = run_check(fleet_of(), {0: 20, 1: 20, 2: 20}, twist="stamped", timeout_s=1.0)
    assert len(report.problems) == 3
    assert str(report.problems[0]) == ("robot 0: subscribes /robot0/cmd_vel as "
                                       "geometry_msgs::msg::dds_::TwistStamped_, not as the inventory's twist = "
                                       "'plain': set twist = \"stamped\" in robot[0]")


@pytest.mark.unit
def test_a_bridge_robot_of_the_other_twist_type_names_the_fix():
    """zenoh-bridge-ros2dds announces each route with its ROS 2 type: a Jazzy TurtleBot3 (TwistStamped) in an
    inventory that says plain is refused, naming the fix, though something subscribes its cmd_vel."""
    fleet = fleet_of(r0={"flavor": "bridge"}, r1={"flavor": "bridge", "twist": "stamped"}, r2={"flavor": "bridge"})
    report, _ = run_check(fleet, {0: 20, 1: 20, 2: 20}, flavor="bridge", twist="stamped", timeout_s=1.0)
    assert [str(p) for p in report.problems] == [
        f"robot {i}: its zenoh-bridge-ros2dds routes robot{i}/cmd_vel to a subscriber of geometry_msgs/msg/TwistStamped,"
        f" not of the inventory's twist = 'plain': set twist = \"stamped\" in robot[{i}]" for i in (0, 2)]


@pytest.mark.unit
def test_bridge_flavour():
    fleet = fleet_of(r0={"flavor": "bridge"}, r1={"flavor": "bridge"}, r2={"flavor": "bridge"})
    report, _ = run_check(fleet, {0: 20, 1: 20, 2: 20}, flavor="bridge")
    assert report.ok, report.text()
    net = MemoryNet()
    b = MemoryBus(net)
    b.subscribe(ros2.bridge_key("robot1", ros2.CMD_VEL), lambda k, p: None)
    sim = Fleet(net, fleet, {0: 20, 1: 20, 2: 20}, flavor="bridge", tokens=False)  # odometry, no cmd_vel listener
    try:
        report = preflight.check(MemoryBus(net), fleet, timeout_s=1.0, window_s=0.6)
    finally:
        sim.close()
    assert [str(p).split(" (")[0] for p in report.problems] == ["robot 0: nothing subscribes robot0/cmd_vel",
                                                                 "robot 2: nothing subscribes robot2/cmd_vel"]


@pytest.mark.unit
def test_a_namespace_given_twice_behind_a_bridge_is_named():
    """A robot in namespace robot1 behind a bridge started with -n /robot1: its cmd_vel is on robot1/robot1/cmd_vel.
    Nothing on the expected key and something on the doubled one: said so, with the fix."""
    fleet = fleet_of(r0={"flavor": "bridge"}, r1={"flavor": "bridge"}, r2={"flavor": "bridge"})
    net = MemoryNet()
    b = MemoryBus(net)
    for i in (0, 2):
        b.subscribe(ros2.bridge_key(f"robot{i}", ros2.CMD_VEL), lambda k, p: None)
    b.subscribe("robot1/robot1/cmd_vel", lambda k, p: None)
    sim = Fleet(net, fleet, {0: 20, 1: 20, 2: 20}, flavor="bridge", tokens=False)
    try:
        report = preflight.check(MemoryBus(net), fleet, timeout_s=1.0, window_s=0.6)
    finally:
        sim.close()
    assert [p.robot for p in report.problems] == [1], report.text()
    assert str(report.problems[0]).startswith("robot 1: nothing subscribes robot1/cmd_vel, but something subscribes "
                                              "robot1/robot1/cmd_vel: the namespace is given twice")
    assert ros2.doubled_bridge_key("", ros2.CMD_VEL) is None


@pytest.mark.unit
def test_unreadable_odometry():
    fleet = fleet_of(r0={"flavor": "bridge"}, r1={"flavor": "bridge"}, r2={"flavor": "bridge"})
    net = MemoryNet()
    b = MemoryBus(net)
    for i in range(3):
        b.subscribe(ros2.bridge_key(f"robot{i}", ros2.CMD_VEL), lambda k, p: None)
    stop = threading.Event()

    def garbage():
        while not stop.wait(0.02):
            for i in range(3):
                b.put(ros2.bridge_key(f"robot{i}", ros2.ODOM), b"\x00\x01\x00\x00nonsense")

    th = threading.Thread(target=garbage, daemon=True)
    th.start()
    try:
        report = preflight.check(MemoryBus(net), fleet, timeout_s=0.5, window_s=0.3)
    finally:
        stop.set()
        th.join(2.0)
    assert len(report.problems) == 3 and "odometry on robot0/odom is unreadable" in str(report.problems[0])


@pytest.mark.integration
def test_no_router_reached_still_prints_the_checks_that_need_no_robot(tmp_path, capsys):
    """`swarm preflight --connect` to a router that is not there printed only the connection error: the
    static checks (a segment too fast for robot 3) were lost with it."""
    from swarm.cli.main import main
    from tests.deploy.helpers import inventory_text
    from tests.integration.helpers import free_port

    inv = tmp_path / "fleet.toml"
    inv.write_text(inventory_text(7, None, r3={"v_max": 0.15}))
    rc = main(["preflight", "--inventory", str(inv), "--scenario", "turtlebot3", "--connect",
               f"tcp/127.0.0.1:{free_port()}", "--start-timeout", "1"])
    out = capsys.readouterr()
    assert rc == 1 and "cannot open a zenoh client session" in out.err, out
    assert "robot 3: leader.segments[0] moves at |v| = 0.15 m/s" in out.out
    assert "pre-flight FAILED: 1 problem" in out.out


@pytest.mark.integration
def test_a_robot_whose_router_does_not_answer_is_a_network_fault_not_its_ros_side(tmp_path, capsys):
    """Robots 0-2 behind their own routers (the inventory's `connect`): one whose port is closed and one whose host
    does not resolve are named as cut off with the cause, and their ROS 2 side is not blamed."""
    from swarm.cli.main import main
    from tests.deploy.helpers import inventory_text
    from tests.integration.helpers import free_port

    closed = f"tcp/127.0.0.1:{free_port()}"
    inv = tmp_path / "fleet.toml"
    inv.write_text(inventory_text(3, None, r0={"connect": closed}, r1={"connect": "tcp/no-such-host.invalid:7447"},
                                  r2={"connect": closed.replace("tcp/", "tls/")}))  # no TLS files here: TCP checked
    rc = main(["preflight", "--inventory", str(inv), "--scenario", "turtlebot3", "--robots", "3",
               "--odom-timeout", "0.5", "--odom-window", "0.2"])
    out = capsys.readouterr().out
    assert rc == 1, out
    assert f"robot 0: cannot reach its zenoh router at {closed}: connection refused" in out, out
    assert "robot 1: cannot reach its zenoh router at tcp/no-such-host.invalid:7447: host 'no-such-host.invalid' unknown" in out, out
    assert f"robot 2: cannot reach its zenoh router at {closed.replace('tcp/', 'tls/')}: connection refused" in out, out
    assert "RMW_IMPLEMENTATION" not in out and "no subscriber" not in out and "CA" not in out, out


@pytest.mark.unit
@pytest.mark.parametrize("flavor", ["rmw_zenoh", "bridge"])
def test_twist_auto_in_the_inventory_takes_either_type(flavor):
    fleet = fleet_of(**{f"r{i}": {"flavor": flavor, "twist": "auto"} for i in range(3)})
    report, _ = run_check(fleet, {0: 20, 1: 20, 2: 20}, flavor=flavor, twist="stamped")
    assert report.ok, report.text()

"""world.ros2_fleet on the in-memory bus: its keys and tokens, its odometry in each robot's own frame,
and its commands (dropped without the attachment in rmw_zenoh flavour, as rmw_zenoh does)."""

from __future__ import annotations

import math

import pytest

from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import ros2
from tests.ros2.helpers import Collector
from world.ros2_fleet import Ros2Fleet

pytestmark = pytest.mark.unit

STARTS = [(1.0, 2.0, 0.5), (-3.0, 0.0, -2.5)]


def fleet_on(net: MemoryNet, flavor: str = "rmw_zenoh", twist: str = "plain", **kw) -> Ros2Fleet:
    f = Ros2Fleet(MemoryBus(net), STARTS, flavor, twist, **kw)
    f.start()
    return f


@pytest.mark.parametrize("flavor, twist, distro, cmd, odom", [
    ("rmw_zenoh", "plain", "jazzy", f"0/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/{ros2.type_hash(ros2.TWIST)}",
     f"0/robot1/odom/nav_msgs::msg::dds_::Odometry_/{ros2.type_hash(ros2.ODOMETRY)}"),
    ("rmw_zenoh", "stamped", "jazzy",
     f"0/robot1/cmd_vel/geometry_msgs::msg::dds_::TwistStamped_/{ros2.type_hash(ros2.TWIST_STAMPED)}",
     f"0/robot1/odom/nav_msgs::msg::dds_::Odometry_/{ros2.type_hash(ros2.ODOMETRY)}"),
    ("rmw_zenoh", "plain", "humble", "0/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/TypeHashNotSupported",
     "0/robot1/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"),
    ("bridge", "stamped", "jazzy", "robot1/cmd_vel", "robot1/odom"),
])
def test_keys_and_liveliness_tokens(flavor, twist, distro, cmd, odom):
    net = MemoryNet()
    f = fleet_on(net, flavor, twist, distro=distro)
    assert f.cmd_keys[1] == cmd and f.odom_keys[1] == odom
    tokens = sorted(k for k in net.tokens)
    if flavor == "bridge":  # each robot's bridge announces its two routes, with their ROS 2 types
        routes = {(r.kind, r.key, r.ros2_type) for r in map(ros2.parse_bridge_route, tokens)}
        assert routes == {("MS", f"robot{i}/cmd_vel", ros2.twist_type(twist)) for i in (0, 1)} | \
            {("MP", f"robot{i}/odom", ros2.ODOMETRY) for i in (0, 1)}
        f.close()
        assert net.tokens == {}
        return
    entities = [ros2.parse_liveliness(k) for k in tokens]
    assert len(entities) == 6 and None not in entities
    robot1 = {e.kind: e for e in entities if e.namespace == "/robot1"}
    assert set(robot1) == {"NN", "MS", "MP"}
    assert robot1["NN"].node == robot1["MS"].node == robot1["MP"].node == "turtlebot3_node"
    assert robot1["MS"].topic == "/robot1/cmd_vel" and robot1["MS"].data_key == cmd
    assert robot1["MP"].topic == "/robot1/odom" and robot1["MP"].data_key == odom
    assert len({e.zid for e in entities}) == 2  # one zenoh session per robot, as one process per robot
    f.close()
    assert net.tokens == {} and not MemoryBus(net).wanted(cmd)


@pytest.mark.parametrize("flavor", ["rmw_zenoh", "bridge"])
def test_odometry_is_in_each_robots_own_frame(flavor):
    net = MemoryNet()
    f = fleet_on(net, flavor, wall_ns=lambda: 1_700_000_000_000_000_000)
    got = Collector()
    MemoryBus(net).subscribe_raw(f.odom_keys[1], got.add)
    f.publish_odom(1, 0.0, *STARTS[1], 0.0, 0.0)  # at its start: the odom frame's origin
    x, y, th = STARTS[1]
    f.publish_odom(1, 2.5, x + 2 * math.cos(th), y + 2 * math.sin(th), th + 0.25, 0.4, 0.1)  # 2 m ahead, turned
    (k0, p0, a0), (k1, p1, a1) = got.snapshot()
    o0, o1 = ros2.decode_odometry(p0), ros2.decode_odometry(p1)
    assert (o0.x, o0.y, o0.yaw, o0.stamp_ns) == (0.0, 0.0, 0.0, 0)
    assert (o1.x, o1.y, o1.yaw) == (pytest.approx(2.0), pytest.approx(0.0, abs=1e-12), pytest.approx(0.25))
    assert (o1.v, o1.w, o1.stamp_ns, o1.frame_id, o1.child_frame_id) == (0.4, 0.1, 2_500_000_000, "odom",
                                                                         "base_footprint")
    if flavor == "bridge":
        assert a0 is None and a1 is None
    else:
        att0, att1 = ros2.decode_attachment(a0), ros2.decode_attachment(a1)
        assert (att0.seq, att1.seq) == (1, 2) and att0.gid == att1.gid
        assert att1.timestamp_ns == 1_700_000_000_000_000_000


def test_commands_without_a_valid_attachment_are_dropped_in_rmw_zenoh_flavour():
    net = MemoryNet()
    f = fleet_on(net, "rmw_zenoh")
    pub = MemoryBus(net)
    ok = ros2.encode_attachment(1, 5, bytes(16))
    pub.put(f.cmd_keys[1], ros2.encode_twist(0.1, 0.2), attachment=ok)
    pub.put(f.cmd_keys[0], ros2.encode_twist(0.3, 0.4))  # no attachment: dropped
    pub.put(f.cmd_keys[0], ros2.encode_twist(0.5, 0.6), attachment=ok[:32])  # not an attachment: dropped
    pub.put(f.cmd_keys[0], b"\x00\x01\x00\x00garbage", attachment=ok)  # not a Twist: bad
    pub.put(f.cmd_keys[0], ros2.encode_twist(0.7, 0.8), attachment=ok)
    assert f.take_commands() == [(1, 0.1, 0.2), (0, 0.7, 0.8)]
    assert (f.dropped_no_attachment, f.bad.count, f.commands) == (2, 1, 2)
    assert f.take_commands() == []


@pytest.mark.parametrize("twist", ["plain", "stamped"])
def test_bridge_flavour_takes_plain_cdr(twist):
    net = MemoryNet()
    f = fleet_on(net, "bridge", twist)
    pub = MemoryBus(net)
    payload = ros2.encode_twist(0.1, -0.2) if twist == "plain" else ros2.encode_twist_stamped(0.1, -0.2, 7)
    pub.put("robot0/cmd_vel", payload)
    pub.put("robot1/cmd_vel", ros2.encode_odometry(ros2.Odometry(0, 0.0, 0.0, 0.0, 0.0, 0.0)))  # wrong type: bad
    assert f.take_commands() == [(0, 0.1, -0.2)]
    assert (f.dropped_no_attachment, f.bad.count) == (0, 1)


def test_bad_arguments_are_refused():
    net = MemoryNet()
    with pytest.raises(ValueError):
        Ros2Fleet(MemoryBus(net), STARTS, "dds", "plain")
    with pytest.raises(ValueError):
        Ros2Fleet(MemoryBus(net), STARTS, "bridge", "plain", distro="iron")
    with pytest.raises(ValueError):
        Ros2Fleet(MemoryBus(net), STARTS, "bridge", "plain", namespace=lambda i: "same")
    with pytest.raises(ValueError):
        Ros2Fleet(MemoryBus(net), [(0.0, math.nan, 0.0)], "bridge", "plain")

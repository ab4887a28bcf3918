"""swarm.drives.ros2 on the in-memory bus: discovery from liveliness tokens, the odometry frame anchored
on the first message, the commands it writes (bytes, attachment, reliability), halt and close."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.drives.ros2 import HALT_REPEATS, DiscoveryError, Ros2Drive
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import ros2
from swarm.proto.protocol import Cmd
from world.ros2_fleet import Ros2Fleet

pytestmark = pytest.mark.unit

WALL_NS = 1_700_000_000_250_000_000


class SpyBus(MemoryBus):
    """A MemoryBus that remembers every put with its options."""

    def __init__(self, net: MemoryNet) -> None:
        super().__init__(net)
        self.puts: list[tuple[str, bytes, bool, bytes | None]] = []

    def put(self, key, payload, reliable=False, loopback=True, attachment=None):
        self.puts.append((key, bytes(payload), reliable, attachment))
        super().put(key, payload, reliable, loopback, attachment)


class Clock:
    def __init__(self, t: float | None = 0.0) -> None:
        self.t = t

    def __call__(self) -> float | None:
        return self.t


def make_drive(net, flavor="bridge", twist="plain", namespace="robot1", initial=(0.0, 0.0, 0.0), now=None, **kw):
    bus = SpyBus(net)
    d = Ros2Drive(bus, namespace=namespace, flavor=flavor, twist=twist, initial_pose=initial,
                  now=now or Clock(), wall_ns=lambda: WALL_NS, discover_timeout_s=kw.pop("discover_timeout_s", 2.0),
                  bridge_look_s=kw.pop("bridge_look_s", 0.05), **kw)
    return d, bus


def odom(x, y, yaw, stamp=0):
    return ros2.encode_odometry(ros2.Odometry(stamp, x, y, yaw, 0.0, 0.0))


# --------------------------------------------------------------------------- frames


def test_the_first_odometry_is_the_start_pose_and_the_rest_follow_it():
    net = MemoryNet()
    start = (2.0, 1.0, math.pi / 2)
    d, _ = make_drive(net, initial=start)
    d.start()
    robot = MemoryBus(net)
    odom0 = (0.3, -0.2, 0.4)  # an odom frame that did not start at zero (IMU yaw, an earlier run)
    robot.put("robot1/odom", odom(*odom0))
    [p0] = d.drain()
    np.testing.assert_allclose((p0.x, p0.y, p0.theta), start, atol=1e-12)
    # the robot drives 1 m straight ahead and turns 0.3 rad: in the swarm frame it is 1 m along +y
    moved = ros2.se2_compose(odom0, (1.0, 0.0, 0.3))
    robot.put("robot1/odom", odom(*moved))
    [p1] = d.drain()
    np.testing.assert_allclose((p1.x, p1.y, p1.theta), (2.0, 2.0, math.pi / 2 + 0.3), atol=1e-12)
    assert (p0.seq, p1.seq) == (0, 1)


def test_heading_is_continuous_across_pi():
    net = MemoryNet()
    d, _ = make_drive(net, initial=(0.0, 0.0, 3.0))
    d.start()
    robot = MemoryBus(net)
    thetas = []
    for yaw in np.linspace(0.0, 2.0 * math.pi + 1.0, 40):  # odometry yaw wraps; the swarm's heading must not
        robot.put("robot1/odom", odom(0.0, 0.0, ros2.wrap(float(yaw))))
        thetas += [p.theta for p in d.drain()]
    np.testing.assert_allclose(thetas, 3.0 + np.linspace(0.0, 2.0 * math.pi + 1.0, 40), atol=1e-9)


def test_poses_wait_for_the_clock_and_bad_odometry_is_counted():
    net = MemoryNet()
    clock = Clock(None)
    d, _ = make_drive(net, initial=(5.0, 5.0, 0.0), now=clock)
    d.start()
    robot = MemoryBus(net)
    robot.put("robot1/odom", odom(10.0, 0.0, 0.0))  # anchors the frame, but no clock yet: no pose
    assert d.drain() == [] and d.unclocked == 1
    robot.put("robot1/odom", b"\x00\x01\x00\x00 not odometry")
    robot.put("robot1/odom", ros2.encode_twist(1.0, 0.0))
    assert d.drain() == [] and d.bad.count == 2
    clock.t = 12.5
    robot.put("robot1/odom", odom(11.0, 0.0, 0.0))
    [p] = d.drain()
    assert (p.t, p.seq) == (12.5, 0)
    np.testing.assert_allclose((p.x, p.y, p.theta), (6.0, 5.0, 0.0), atol=1e-12)  # anchored on the first message


def test_wait_blocks_for_odometry_and_wake_returns_it_empty():
    import threading

    net = MemoryNet()
    d, _ = make_drive(net)
    d.start()
    out: list = []
    th = threading.Thread(target=lambda: out.append(d.wait()), daemon=True)
    th.start()
    MemoryBus(net).put("robot1/odom", odom(0.0, 0.0, 0.0))
    th.join(5)
    assert len(out) == 1 and [p.seq for p in out[0]] == [0]
    th = threading.Thread(target=lambda: out.append(d.wait()), daemon=True)
    th.start()
    d.wake()
    th.join(5)
    assert out[1] == [] and not th.is_alive()


# --------------------------------------------------------------------------- commands


@pytest.mark.parametrize("flavor, twist", [("bridge", "plain"), ("bridge", "stamped"), ("rmw_zenoh", "plain"),
                                           ("rmw_zenoh", "stamped")])
def test_commands_bytes_attachment_and_reliability(flavor, twist):
    net = MemoryNet()
    fleet = Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0), (0.0, 0.0, 0.0)], flavor, twist)
    fleet.start()
    d, bus = make_drive(net, flavor, twist)
    d.start()
    d.send(Cmd(t=1.0, seq=1, v=0.15, w=-0.4))
    d.send(Cmd(t=1.1, seq=2, v=0.2, w=0.0))
    assert fleet.take_commands() == [(1, 0.15, -0.4), (1, 0.2, 0.0)]
    (k1, p1, r1, a1), (k2, p2, r2, a2) = bus.puts
    assert k1 == k2 == fleet.cmd_keys[1] and r1 and r2
    if twist == "plain":
        assert p1 == ros2.encode_twist(0.15, -0.4)
    else:
        assert p1 == ros2.encode_twist_stamped(0.15, -0.4, WALL_NS, "base_link")
    if flavor == "bridge":
        assert a1 is None and a2 is None
    else:
        att1, att2 = ros2.decode_attachment(a1), ros2.decode_attachment(a2)
        assert (att1.seq, att2.seq) == (1, 2) and att1.timestamp_ns == WALL_NS and att1.gid == att2.gid == d.gid
    assert d.halted is None and d.sent == 2


def test_halt_latches_until_the_next_send_and_close_halts_and_releases():
    net = MemoryNet()
    fleet = Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0), (0.0, 0.0, 0.0)], "rmw_zenoh", "plain")
    fleet.start()
    d, bus = make_drive(net, "rmw_zenoh")
    assert d.halted == "not started"
    d.start()
    d.send(Cmd(t=0.0, seq=0, v=0.2, w=0.1))
    d.halt("watchdog")
    assert d.halted == "watchdog"
    assert fleet.take_commands() == [(1, 0.2, 0.1)] + [(1, 0.0, 0.0)] * HALT_REPEATS
    d.send(Cmd(t=0.1, seq=1, v=0.1, w=0.0))
    assert d.halted is None
    with pytest.raises(ValueError):
        d.send(Cmd(t=0.2, seq=2, v=math.nan, w=0.0))
    assert d.halted.startswith("non-finite")
    assert fleet.take_commands() == [(1, 0.1, 0.0)] + [(1, 0.0, 0.0)] * HALT_REPEATS
    drive_tokens = [k for k in net.tokens if ros2.parse_liveliness(k).node == "swarm_drive"]
    assert len(drive_tokens) == 3
    d.close()
    assert d.halted == "drive closed" and fleet.take_commands() == [(1, 0.0, 0.0)] * HALT_REPEATS
    assert not MemoryBus(net).wanted(d.odom_key)  # the odometry subscription is gone
    assert not [k for k in net.tokens if ros2.parse_liveliness(k).node == "swarm_drive"]
    seqs = [ros2.decode_attachment(a).seq for _, _, _, a in bus.puts]
    assert seqs == list(range(1, len(bus.puts) + 1))
    d.close()  # twice is fine
    assert len(bus.puts) == len(seqs)


def test_send_before_start_is_refused():
    d, _ = make_drive(MemoryNet())
    with pytest.raises(RuntimeError):
        d.send(Cmd(t=0.0, seq=0, v=0.0, w=0.0))
    d.halt("shutdown")  # halting an unstarted drive only latches
    assert d.halted == "shutdown"


@pytest.mark.parametrize("kw", [dict(flavor="dds"), dict(twist="fast"), dict(namespace="1robot"),
                                dict(initial=(0.0, math.inf, 0.0)), dict(domain=-1), dict(discover_timeout_s=0)])
def test_bad_arguments_are_refused(kw):
    with pytest.raises(ValueError):
        make_drive(MemoryNet(), **kw)


# --------------------------------------------------------------------------- discovery


@pytest.mark.parametrize("twist, distro", [("plain", "jazzy"), ("stamped", "jazzy"), ("plain", "humble")])
def test_discovery_finds_the_exact_keys_of_its_robot(twist, distro):
    net = MemoryNet()
    fleet = Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0)] * 3, "rmw_zenoh", twist, domain=4, distro=distro)
    fleet.start()
    Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0)] * 3, "rmw_zenoh", twist, domain=5).start()  # another domain
    d, _ = make_drive(net, "rmw_zenoh", twist, namespace="/robot2", domain=4)
    d.start()
    assert (d.cmd_key, d.odom_key) == (fleet.cmd_keys[2], fleet.odom_keys[2])
    assert d.cmd_key.endswith("TypeHashNotSupported") == (distro == "humble")
    own = [ros2.parse_liveliness(k) for k in net.tokens if ros2.parse_liveliness(k).node == "swarm_drive"]
    assert {(e.kind, e.namespace, e.topic) for e in own} == {("NN", "/robot2", None), ("MP", "/robot2", "/robot2/cmd_vel"),
                                                             ("MS", "/robot2", "/robot2/odom")}
    assert {e.data_key for e in own if e.topic} == {d.cmd_key, d.odom_key}


def test_discovery_names_a_twist_mismatch():
    net = MemoryNet()
    Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0)] * 2, "rmw_zenoh", "stamped").start()
    d, _ = make_drive(net, "rmw_zenoh", "plain", discover_timeout_s=0.2)
    with pytest.raises(DiscoveryError) as e:
        d.start()
    msg = str(e.value)
    assert msg.startswith("ROS 2 robot robot1: found no subscriber of /robot1/cmd_vel as geometry_msgs/msg/Twist on "
                          "domain 0 within 0.2 s")
    assert "use --twist stamped" in msg and "/robot1/turtlebot3_node" in msg
    assert "publisher of" not in msg  # its odometry was there


def test_discovery_with_no_robot_says_what_to_check():
    net = MemoryNet()
    d, _ = make_drive(net, "rmw_zenoh", discover_timeout_s=0.2, namespace="robot9")
    with pytest.raises(DiscoveryError, match="No ROS 2 entity at all.*rmw_zenoh_cpp.*--ros-flavor bridge"):
        d.start()
    Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0)] * 2, "rmw_zenoh", "plain").start()
    with pytest.raises(DiscoveryError, match=r"/robot9/cmd_vel.*/robot9/odom.*Seen 2 node\(s\): /robot0/turtlebot3_node"):
        d.start()


@pytest.mark.parametrize("twist", ["plain", "stamped"])
def test_twist_auto_takes_the_type_the_robot_subscribes(twist):
    """--twist auto: rmw_zenoh from the robot's token, bridge from the route its zenoh-bridge-ros2dds announces;
    the commands then arrive in that type (the fleet decodes them as such)."""
    for flavor in ("rmw_zenoh", "bridge"):
        net = MemoryNet()
        fleet = Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0)] * 2, flavor, twist)
        fleet.start()
        d, _ = make_drive(net, flavor, "auto")
        d.start()
        assert (d.twist, d.cmd_type) == (twist, ros2.twist_type(twist)), flavor
        d.send(Cmd(1, 1, 0.5, -0.25))
        assert fleet.take_commands()[-1] == (1, 0.5, -0.25), flavor


def test_a_bridge_robot_of_the_other_twist_type_is_refused_naming_the_fix():
    """The bridge passes any bytes on: a TwistStamped read as a Twist (or the reverse) is nonsense or nothing at the
    robot. The route the bridge announces says the type, and a --twist that differs is refused, naming the right
    one."""
    net = MemoryNet()
    Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0)] * 2, "bridge", "stamped").start()
    d, _ = make_drive(net, "bridge", "plain")
    with pytest.raises(DiscoveryError, match=r"subscribes /robot1/cmd_vel as geometry_msgs/msg/TwistStamped .*"
                                             r"use --twist stamped \(or auto\)"):
        d.start()
    d, _ = make_drive(net, "bridge", "stamped")
    d.start()  # the right one


def test_a_bridge_started_with_the_robots_namespace_again_is_named():
    """The robot's nodes in /robot1 behind a bridge started with -n /robot1: its route is robot1/robot1/cmd_vel."""
    net = MemoryNet()
    MemoryBus(net).token(ros2.BridgeRoute("ab12", "MS", "robot1/robot1/cmd_vel", ros2.TWIST).token)
    d, _ = make_drive(net, "bridge", "auto")
    with pytest.raises(DiscoveryError, match="namespace is given twice.*without -n"):
        d.start()


@pytest.mark.parametrize("twist", ["plain", "stamped"])
def test_a_bridge_without_route_tokens_is_asked_through_its_admin_space(twist):
    """A bridge whose route token does not come: its admin space (`@/<zid>/ros2/route/topic/sub/<key>`, a JSON object
    with the route's `ros2_type`) says the type; auto takes it, the other --twist is refused naming the fix."""
    import json

    net = MemoryNet()
    typ = ros2.twist_type(twist)
    route = json.dumps({"dds_writer": "0110abcd", "is_active": True, "local_nodes": ["/robot1/turtlebot3_node"],
                        "remote_routes": [], "ros2_name": "/robot1/cmd_vel", "ros2_type": typ}).encode()
    MemoryBus(net).serve("@/ab12cd/ros2/route/topic/sub/robot1/cmd_vel", lambda asked: route)
    d, _ = make_drive(net, "bridge", "auto")
    d.start()
    assert d.cmd_type == typ
    other = "plain" if twist == "stamped" else "stamped"
    d, _ = make_drive(net, "bridge", other)
    with pytest.raises(DiscoveryError, match=f"use --twist {twist}"):
        d.start()


@pytest.mark.parametrize("payload", [b"", b"{", b"[]", b"null", b'{"ros2_type": 7}', b'{"ros2_type": "Twist"}',
                                     b"\xff\xfe", b"[" * 100_000, b'{"ros2_type": "' + b"a" * 70_000 + b'"}'])
def test_an_admin_reply_that_is_not_a_route_says_nothing(payload):
    assert ros2.bridge_admin_type(payload) is None


def test_a_legacy_bridge_route_is_read_too():
    net = MemoryNet()
    MemoryBus(net).token(ros2.BridgeRoute("ab12", "MS", "robot1/cmd_vel", ros2.TWIST_STAMPED, legacy=True).token)
    d, _ = make_drive(net, "bridge", "auto")
    d.start()
    assert d.cmd_type == ros2.TWIST_STAMPED


def test_a_route_that_comes_late_sets_the_type_or_is_said(caplog):
    """The robot's nodes come up after the drive started: auto takes the type of the route then (the next command
    is in it); a given --twist of the other type is said as an error (the robot takes none of its commands)."""
    net = MemoryNet()
    d, bus = make_drive(net, "bridge", "auto")
    d.start()
    assert d.cmd_type == ros2.TWIST
    MemoryBus(net).token(ros2.BridgeRoute("ab12", "MS", "robot1/cmd_vel", ros2.TWIST_STAMPED).token)
    assert d.cmd_type == ros2.TWIST_STAMPED
    d.send(Cmd(1, 1, 0.1, 0.0))
    assert ros2.decode_twist_stamped(bus.puts[-1][1]) == (0.1, 0.0)
    net = MemoryNet()
    d, _ = make_drive(net, "bridge", "plain")
    d.start()
    with caplog.at_level("ERROR", logger="swarm.drive.ros2"):
        MemoryBus(net).token(ros2.BridgeRoute("ab12", "MS", "robot1/cmd_vel", ros2.TWIST_STAMPED).token)
    assert "give --twist stamped" in caplog.text and d.cmd_type == ros2.TWIST
    d.close()
    assert not net.tokens or all("swarm_drive" not in k for k in net.tokens)


def test_a_bridge_that_announces_no_route_is_said_and_commanded_as_given(caplog):
    """An old bridge (or a robot whose nodes are not up yet) announces nothing: the drive says it could not check
    the type, and commands in the one given (auto: plain, or the --distro's TurtleBot3 default)."""
    net = MemoryNet()
    d, bus = make_drive(net, "bridge", "auto")
    with caplog.at_level("WARNING", logger="swarm.drive.ros2"):
        d.start()
    assert d.cmd_type == ros2.TWIST and "no zenoh-bridge-ros2dds announces a route for robot1/cmd_vel" in caplog.text
    d.send(Cmd(1, 1, 0.1, 0.0))
    assert ros2.decode_twist(bus.puts[-1][1]) == (0.1, 0.0)
    for distro, twist in (("jazzy", ros2.TWIST_STAMPED), ("rolling", ros2.TWIST_STAMPED), ("humble", ros2.TWIST)):
        d, _ = make_drive(net, "bridge", "auto", distro=distro)  # --distro: a TurtleBot3's default there
        d.start()
        assert d.cmd_type == twist, distro
    with pytest.raises(ValueError, match="distro"):
        make_drive(net, "bridge", "auto", distro="iron")


def test_bridge_route_tokens_read_back_and_nothing_else_reads_as_one():
    """Both forms: zenoh-bridge-ros2dds 1.x (`@/<zid>/@ros2_lv/...`, what the simulated bridges announce) and 0.x
    (`@ros2_lv/<zid>/...`)."""
    r = ros2.BridgeRoute("0123abcd", "MP", "robot1/odom", ros2.ODOMETRY)
    assert r.token == "@/0123abcd/@ros2_lv/MP/robot1\u00a7odom/nav_msgs\u00a7msg\u00a7Odometry/:1:0:0,10"
    assert ros2.parse_bridge_route(r.token) == r
    old = ros2.BridgeRoute("0123abcd", "MS", "robot1/cmd_vel", ros2.TWIST, legacy=True)
    assert old.token == "@ros2_lv/0123abcd/MS/robot1\u00a7cmd_vel/geometry_msgs\u00a7msg\u00a7Twist/:1:0:0,10"
    assert ros2.parse_bridge_route(old.token) == old
    assert ros2.parse_bridge_route("@/z/@ros2_lv/MS/a/geometry_msgs\u00a7msg\u00a7Twist/K:1:0:0,10:typehash=x").ros2_type \
        == ros2.TWIST  # a 1.0.4+ bridge's QoS chunk with the type hash
    fleet = Ros2Fleet(MemoryBus(MemoryNet()), [(0.0, 0.0, 0.0)], "rmw_zenoh", "plain")
    for key in [e.key for e in fleet.entities(0)] + ["@ros2_lv/z/XX/a/geometry_msgs\u00a7msg\u00a7Twist/q",
                                                    "@/z/@ros2/MS/a/geometry_msgs\u00a7msg\u00a7Twist/q",
                                                    "@/z/@ros2_lv/MS/a/geometry_msgs\u00a7msg\u00a7Twist",
                                                    "@ros2_lv/z/MS/a/notatype/q", "@ros2_lv/z/MS/a*/b/q", 7]:
        assert ros2.parse_bridge_route(key) is None, key
    assert ros2.twist_of("geometry_msgs::msg::dds_::TwistStamped_") == "stamped" and ros2.twist_of(ros2.ODOMETRY) is None


# --------------------------------------------------------------------------- the rmw_zenoh releases


@pytest.mark.parametrize("release", ["v1", "v2"])
@pytest.mark.parametrize("given", ["auto", "v1", "v2"])
def test_commands_carry_the_attachment_of_the_robots_release(release, given, caplog):
    """A fleet of one rmw_zenoh release (its odometry carries that form, and it drops a command in the other): the
    drive in auto takes the form of the first odometry and every command arrives; a form given that differs is
    said, as an error, and the robot takes nothing."""
    net = MemoryNet()
    fleet = Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0), (0.0, 0.0, 0.0)], "rmw_zenoh", "plain", attachment=release)
    fleet.start()
    d, bus = make_drive(net, "rmw_zenoh", attachment=given)
    d.start()
    fleet.publish_odom(1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert len(d.drain()) == 1 and d.robot_attachment == release
    d.send(Cmd(t=1.0, seq=1, v=0.15, w=-0.4))
    fits = given in ("auto", release)
    assert fleet.take_commands() == ([(1, 0.15, -0.4)] if fits else [])
    assert fleet.dropped_no_attachment == (0 if fits else 1)
    assert ros2.attachment_form(bus.puts[-1][3]) == (release if fits else given)
    said = [r.getMessage() for r in caplog.records if "rmw_zenoh drops every command" in r.getMessage()]
    assert bool(said) == (not fits)


def test_the_attachment_forms_are_zenoh_ext_serializations():
    """v1: each value after its name as a zenoh-ext string (77 bytes); v2: the 33 bytes. Checked against zenoh-ext's
    own serializer, and each form refuses the other."""
    ext = pytest.importorskip("zenoh.ext")
    gid = bytes(range(16))
    v1 = ros2.encode_attachment(7, WALL_NS, gid, "v1")
    assert v1 == bytes(ext.z_serialize(("sequence_number", ext.Int64(7), "source_timestamp", ext.Int64(WALL_NS),
                                        "source_gid", gid)))
    assert ros2.encode_attachment(7, WALL_NS, gid) == bytes(ext.z_serialize((ext.Int64(7), ext.Int64(WALL_NS), gid)))
    assert len(v1) == ros2.ATTACHMENT_SIZE_V1 == 77
    assert ros2.decode_attachment(v1, "v1") == ros2.Attachment(7, WALL_NS, gid)
    with pytest.raises(ros2.Ros2Error, match="a v2 attachment is 33 bytes, got 77"):
        ros2.decode_attachment(v1)
    renamed = v1.replace(b"source_gid", b"source_gix")
    with pytest.raises(ros2.Ros2Error, match="names source_gid there"):
        ros2.decode_attachment(renamed, "v1")
    assert [ros2.attachment_form(a) for a in (v1, ros2.encode_attachment(7, 0, gid), renamed, None, b"")] == \
        ["v1", "v2", None, None, None]


def test_commands_that_do_not_move_the_robot_are_said_within_two_seconds(caplog):
    """Commands that move go out and the odometry stays where it was (here: the robot's release drops them): said
    once, after STILL_SAY_S, naming what to check; odometry that moves, or a stop, says nothing."""
    import swarm.drives.ros2 as drive_mod

    now = [100.0]
    net = MemoryNet()
    fleet = Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0), (0.0, 0.0, 0.0)], "rmw_zenoh", "plain", attachment="v1")
    fleet.start()
    d, _ = make_drive(net, "rmw_zenoh", attachment="v2", monotonic=lambda: now[0])  # the wrong form: nothing taken
    d.start()
    for k in range(30):  # 3 s of commands at 10 Hz, and odometry at the same place
        fleet.publish_odom(1, 0.1 * k, 0.0, 0.0, 0.0, 0.0, 0.0)
        d.drain()
        d.send(Cmd(t=0.1 * k, seq=k, v=0.2, w=0.0))
        now[0] += 0.1
        if now[0] - 100.0 < drive_mod.STILL_SAY_S - 0.15:
            assert not d.still_said
    assert d.still_said and fleet.take_commands() == []
    said = [r.getMessage() for r in caplog.records if "did not move" in r.getMessage()]
    assert len(said) == 1 and "the attachment form, here v2" in said[0]
    moving, _ = make_drive(MemoryNet(), "bridge", monotonic=lambda: now[0])
    moving.cmd_key = "robot1/cmd_vel"
    for k in range(30):  # odometry that follows the commands
        moving.send(Cmd(t=0.1 * k, seq=k, v=0.2, w=0.0))
        moving._watch_motion((0.02 * k, 0.0, 0.0))
        now[0] += 0.1
    assert not moving.still_said


def test_an_odometry_reset_is_re_anchored_where_the_robot_was(caplog):
    """The robot's node restarts and its odometry starts again at (0, 0, 0): the drive re-anchors the new frame at the
    robot's last pose (no jump in the swarm's frame), counts it and says so. A big step elsewhere (samples lost in
    between) is motion, and so is a return near the origin."""
    net = MemoryNet()
    pub = MemoryBus(net)
    d, _ = make_drive(net, "bridge", initial=(5.0, 2.0, 0.0))
    d.start()
    for x in (0.0, 0.4, 1.6, 1.61):  # 1.2 m between two samples: a gap, not a reset
        pub.put(d.odom_key, odom(x, 0.0, 0.0))
    assert [round(p.x, 6) for p in d.drain()] == [5.0, 5.4, 6.6, 6.61] and d.resets == 0
    pub.put(d.odom_key, odom(0.0, 0.0, 0.0))  # restarted
    pub.put(d.odom_key, odom(0.01, 0.0, 0.0))
    after = d.drain()
    assert d.resets == 1 and [round(p.x, 6) for p in after] == [6.61, 6.62] and {p.y for p in after} == {2.0}
    assert any("jumped from (1.610, 0.000, 0.000) to (0.000, 0.000, 0.000)" in r.getMessage() for r in caplog.records)
    pub.put(d.odom_key, odom(0.01, 0.0, 1.2))
    pub.put(d.odom_key, odom(0.0, 0.0, 0.0))  # back at the origin from a heading 1.2 rad away: restarted again
    turned = d.drain()
    assert d.resets == 2 and turned[1].theta == pytest.approx(turned[0].theta) == pytest.approx(1.2)
    pub.put(d.odom_key, odom(0.3, 0.0, 0.0))
    pub.put(d.odom_key, odom(0.0, 0.0, 0.0))  # 0.3 m back to the origin: motion
    d.drain()
    assert d.resets == 2


def test_gids_are_derived_from_the_entitys_token_as_rmw_zenoh_derives_them():
    """rmw_zenoh's gid of an entity is XXH3-128 of its liveliness token's key, low 64 bits then high, little-endian:
    the drive's commands and the fleet's odometry carry the gid of the publisher their tokens announce, so
    `ros2 topic info -v` and the samples agree."""
    assert ros2.entity_gid("") == bytes.fromhex("99aa06d3014798d86001c324468d497f")[::-1]  # XXH3-128 of "" (seed 0)
    net = MemoryNet()
    fleet = Ros2Fleet(MemoryBus(net), [(0.0, 0.0, 0.0)] * 2, "rmw_zenoh", "plain")
    fleet.start()
    d, bus = make_drive(net, "rmw_zenoh", "plain")
    d.start()
    mine = [ros2.parse_liveliness(k) for k in net.tokens if ros2.parse_liveliness(k).node == "swarm_drive"]
    (pub,) = [e for e in mine if e.kind == "MP"]
    d.send(Cmd(1, 1, 0.1, 0.0))
    assert ros2.decode_attachment(bus.puts[-1][3]).gid == ros2.entity_gid(pub.key)
    got = []
    MemoryBus(net).subscribe_raw(fleet.odom_keys[1], lambda k, p, a: got.append(a))
    fleet.publish_odom(1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert ros2.decode_attachment(got[-1]).gid == ros2.entity_gid(fleet.entities(1)[2].key)

"""swarm.proto.ros2 at the byte level: type hashes, rmw_zenoh and bridge keys, liveliness tokens,
the 33-byte attachment, CDR bytes of Twist, TwistStamped and Odometry, planar frames, and hostile bytes."""

from __future__ import annotations

import importlib.util
import math
import struct
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.proto import ros2

pytestmark = pytest.mark.unit

# The hashes as published for Jazzy (the same strings appear in rmw_zenoh-compatible code bases).
TWIST_HASH = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
TWIST_STAMPED_HASH = "RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64"
ODOMETRY_HASH = "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"


def test_type_hashes_equal_the_published_ones():
    assert ros2.type_hash(ros2.TWIST) == TWIST_HASH
    assert ros2.type_hash(ros2.TWIST_STAMPED) == TWIST_STAMPED_HASH
    assert ros2.type_hash(ros2.ODOMETRY) == ODOMETRY_HASH


@pytest.mark.parametrize("domain, ns, topic, typename, hash_, key", [
    (0, "robot1", "cmd_vel", ros2.TWIST, TWIST_HASH,
     f"0/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TWIST_HASH}"),
    (0, "/robot1", "odom", ros2.ODOMETRY, ODOMETRY_HASH,
     f"0/robot1/odom/nav_msgs::msg::dds_::Odometry_/{ODOMETRY_HASH}"),
    (0, "robot1/", "cmd_vel", ros2.TWIST_STAMPED, TWIST_STAMPED_HASH,
     f"0/robot1/cmd_vel/geometry_msgs::msg::dds_::TwistStamped_/{TWIST_STAMPED_HASH}"),
    (42, "lab/tb3_2", "cmd_vel", ros2.TWIST, ros2.NO_HASH,
     "42/lab/tb3_2/cmd_vel/geometry_msgs::msg::dds_::Twist_/TypeHashNotSupported"),
    (3, "", "odom", ros2.ODOMETRY, ros2.NO_HASH, "3/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"),
])
def test_rmw_zenoh_keys(domain, ns, topic, typename, hash_, key):
    assert ros2.rmw_key(domain, ros2.topic_name(ns, topic), typename, hash_) == key


@pytest.mark.parametrize("ns, topic, key", [
    ("robot1", "cmd_vel", "robot1/cmd_vel"), ("/robot1", "odom", "robot1/odom"),
    ("lab/tb3_2", "cmd_vel", "lab/tb3_2/cmd_vel"), ("", "cmd_vel", "cmd_vel"), ("/", "odom", "odom"),
])
def test_bridge_keys(ns, topic, key):
    assert ros2.bridge_key(ns, topic) == key


@pytest.mark.parametrize("call", [
    lambda: ros2.rmw_key(-1, "/robot1/cmd_vel", ros2.TWIST, TWIST_HASH),
    lambda: ros2.rmw_key(True, "/robot1/cmd_vel", ros2.TWIST, TWIST_HASH),
    lambda: ros2.rmw_key(0, "/robot1/cmd_vel", ros2.TWIST, "RIHS01_abc"),
    lambda: ros2.rmw_key(0, "/robot1/cmd*", ros2.TWIST, TWIST_HASH),
    lambda: ros2.rmw_key(0, "/robot1/cmd_vel", "Twist", TWIST_HASH),
    lambda: ros2.bridge_key("robot 1", "cmd_vel"),
    lambda: ros2.bridge_key("1robot", "cmd_vel"),
    lambda: ros2.bridge_key("robot1//x", "cmd_vel"),
    lambda: ros2.bridge_key("robot1", "cmd/vel*"),
    lambda: ros2.twist_type("twisty"),
    lambda: ros2.check_flavor("dds"),
])
def test_bad_names_are_refused(call):
    with pytest.raises(ros2.Ros2Error):
        call()


def test_dds_type_names():
    assert ros2.dds_type(ros2.TWIST) == "geometry_msgs::msg::dds_::Twist_"
    assert ros2.dds_type(ros2.ODOMETRY) == "nav_msgs::msg::dds_::Odometry_"
    assert ros2.ros_type("geometry_msgs::msg::dds_::TwistStamped_") == ros2.TWIST_STAMPED
    assert ros2.twist_type("plain") == ros2.TWIST and ros2.twist_type("stamped") == ros2.TWIST_STAMPED
    with pytest.raises(ros2.Ros2Error):
        ros2.ros_type("geometry_msgs/msg/Twist")


# --------------------------------------------------------------------------- liveliness tokens

# A token as an rmw_zenoh node writes it (the layout of its liveliness_utils.cpp): the cmd_vel
# subscription of /robot1/turtlebot3_node, default enclave, keep-last 10, reliable, volatile.
SUB_TOKEN = ("@ros2_lv/0/8f2d0c31a4be47d1a51c3a2b6e8e9f10/0/12/MS/%/%robot1/turtlebot3_node/%robot1%cmd_vel/"
             f"geometry_msgs::msg::dds_::Twist_/{TWIST_HASH}/::,10:,:,:,,")


def test_parse_a_subscription_token():
    e = ros2.parse_liveliness(SUB_TOKEN)
    assert e == ros2.Entity(domain=0, zid="8f2d0c31a4be47d1a51c3a2b6e8e9f10", nid="0", eid="12", kind="MS",
                            enclave="/", namespace="/robot1", node="turtlebot3_node", topic="/robot1/cmd_vel",
                            dds_type="geometry_msgs::msg::dds_::Twist_", type_hash=TWIST_HASH, qos="::,10:,:,:,,")
    assert e.data_key == f"0/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TWIST_HASH}"
    assert e.key == SUB_TOKEN


def test_parse_node_and_humble_tokens():
    node = ros2.parse_liveliness("@ros2_lv/5/ab12/3/3/NN/%/%/talker")
    assert (node.domain, node.kind, node.namespace, node.node, node.topic) == (5, "NN", "/", "talker", None)
    with pytest.raises(ros2.Ros2Error):
        node.data_key
    humble = ros2.parse_liveliness("@ros2_lv/0/ab12/0/5/MP/%/%robot2/turtlebot3_node/%robot2%odom/"
                                   "nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported/1:2:1,10:,:,:,,")
    assert humble.data_key == "0/robot2/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"


@pytest.mark.parametrize("key", [
    SUB_TOKEN.replace("@ros2_lv/", "@ros2/"),
    SUB_TOKEN.replace("/MS/", "/XX/"),
    SUB_TOKEN.replace("@ros2_lv/0/", "@ros2_lv/zero/"),
    SUB_TOKEN.rsplit("/", 1)[0],  # 12 chunks
    SUB_TOKEN + "/extra",
    SUB_TOKEN.replace("/12/", "//"),
    "@ros2_lv/0/ab12/0/5/MS/%/%/node",  # a subscription without its topic
    "@ros2_lv/0/ab12/0/5/NN/%/%/node/%t/x/y/q",  # a node with one
    "", "swarm/default/alive/robot/1", "@ros2_lv/0/**",
])
def test_parse_refuses_what_is_not_a_token(key):
    assert ros2.parse_liveliness(key) is None


def test_entity_key_round_trips_and_refuses_unparsable_entities():
    e = ros2.Entity(7, "c0ffee", "0", "4", "MP", "/", "/lab/tb3", "turtlebot3_node", "/lab/tb3/odom",
                    ros2.dds_type(ros2.ODOMETRY), ros2.type_hash(ros2.ODOMETRY), ros2.qos_string())
    assert e.key.startswith("@ros2_lv/7/c0ffee/0/4/MP/%/%lab%tb3/turtlebot3_node/%lab%tb3%odom/")
    assert ros2.parse_liveliness(e.key) == e
    with pytest.raises(ros2.Ros2Error):
        ros2.Entity(7, "c0ffee", "0", "4", "MP", "/", "/lab", "node").key  # a publisher needs a topic
    assert ros2.liveliness_any(7) == "@ros2_lv/7/**"
    # as rmw_zenoh writes it: a field equal to rmw's default profile is left empty (the bytes of the token, from which
    # rmw_zenoh derives the entity's gid)
    assert ros2.qos_string() == "::,:,:,:,,"
    assert ros2.qos_string(5, reliable=False, transient_local=True) == "2:1:,5:,:,:,,"


# --------------------------------------------------------------------------- attachment


@pytest.mark.parametrize("seq, ts", [(1, 1_700_000_000_123_456_789), (0, 0), (-5, -1), (2**63 - 1, -(2**63))])
def test_attachment_is_33_bytes_in_the_zenoh_ext_layout(seq, ts):
    from zenoh.ext import Int64, z_serialize

    gid = bytes(range(100, 116))
    att = ros2.encode_attachment(seq, ts, gid)
    assert len(att) == ros2.ATTACHMENT_SIZE == 33
    assert att == struct.pack("<qq", seq, ts) + b"\x10" + gid  # int64 LE, int64 LE, length 16, gid
    assert att == z_serialize((Int64(seq), Int64(ts), gid)).to_bytes()
    assert ros2.decode_attachment(att) == ros2.Attachment(seq, ts, gid)


@pytest.mark.parametrize("data", [None, b"", bytes(32), bytes(34), bytes(16) + b"\x0f" + bytes(16), "x" * 33])
def test_bad_attachments_are_refused(data):
    with pytest.raises(ros2.Ros2Error):
        ros2.decode_attachment(data)


@pytest.mark.parametrize("args", [(2**63, 0, bytes(16)), (0, 0, bytes(15)), (0, 0.5, bytes(16)), (True, 0, bytes(16))])
def test_attachment_encoder_refuses_bad_values(args):
    with pytest.raises(ros2.Ros2Error):
        ros2.encode_attachment(*args)


# --------------------------------------------------------------------------- CDR bytes

CDR_LE = b"\x00\x01\x00\x00"


def _rosbags():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _twist_msg(ts, v, w):
    V = ts.types["geometry_msgs/msg/Vector3"]
    return ts.types["geometry_msgs/msg/Twist"](linear=V(x=v, y=0.0, z=0.0), angular=V(x=0.0, y=0.0, z=w))


def _header(ts, ns, frame):
    return ts.types["std_msgs/msg/Header"](
        stamp=ts.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame)


def test_twist_bytes_equal_rosbags_and_the_cdr_layout():
    ts = _rosbags()
    ours = ros2.encode_twist(0.25, -1.5)
    assert ours == bytes(ts.serialize_cdr(_twist_msg(ts, 0.25, -1.5), ros2.TWIST, little_endian=True))
    assert ours == CDR_LE + struct.pack("<6d", 0.25, 0, 0, 0, 0, -1.5)
    assert len(ours) == 52
    assert ros2.decode_twist(ours) == (0.25, -1.5)


def test_twist_stamped_bytes_equal_rosbags_and_the_cdr_layout():
    ts = _rosbags()
    stamp = 1_700_000_123_987_654_321
    ours = ros2.encode_twist_stamped(0.25, -1.5, stamp)
    msg = ts.types["geometry_msgs/msg/TwistStamped"](header=_header(ts, stamp, "base_link"),
                                                    twist=_twist_msg(ts, 0.25, -1.5))
    assert ours == bytes(ts.serialize_cdr(msg, ros2.TWIST_STAMPED, little_endian=True))
    # sec, nanosec, the frame's length with its NUL, the frame, padding to 8, the twist
    body = struct.pack("<iIi", 1_700_000_123, 987_654_321, 10) + b"base_link\x00" + b"\x00\x00"
    assert ours == CDR_LE + body + struct.pack("<6d", 0.25, 0, 0, 0, 0, -1.5)
    assert ros2.decode_twist_stamped(ours) == (0.25, -1.5)


def test_odometry_bytes_equal_rosbags_and_the_cdr_layout():
    ts = _rosbags()
    T = ts.types
    o = ros2.Odometry(stamp_ns=12_500_000_000, x=1.5, y=-2.0, yaw=0.75, v=0.2, w=-0.3)
    ours = ros2.encode_odometry(o)
    qz, qw = math.sin(0.375), math.cos(0.375)
    pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=1.5, y=-2.0, z=0.0),
                                       orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=qz, w=qw))
    msg = T["nav_msgs/msg/Odometry"](
        header=_header(ts, 12_500_000_000, "odom"), child_frame_id="base_footprint",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=_twist_msg(ts, 0.2, -0.3), covariance=np.zeros(36)))
    assert ours == bytes(ts.serialize_cdr(msg, ros2.ODOMETRY, little_endian=True))
    body = (struct.pack("<iIi", 12, 500_000_000, 5) + b"odom\x00" + b"\x00" * 3
            + struct.pack("<i", 15) + b"base_footprint\x00" + b"\x00"
            + struct.pack("<7d", 1.5, -2.0, 0.0, 0.0, 0.0, qz, qw) + bytes(36 * 8)
            + struct.pack("<6d", 0.2, 0, 0, 0, 0, -0.3) + bytes(36 * 8))
    assert ours == CDR_LE + body and len(ours) == 724
    back = ros2.decode_odometry(ours)
    assert back == ros2.Odometry(12_500_000_000, 1.5, -2.0, pytest.approx(0.75, abs=1e-15), 0.2, -0.3)


def test_decoders_take_what_rosbags_writes_big_endian_too():
    ts = _rosbags()
    be = bytes(ts.serialize_cdr(_twist_msg(ts, 1.0, 2.0), ros2.TWIST, little_endian=False))
    assert be[:2] == b"\x00\x00" and ros2.decode_twist(be) == (1.0, 2.0)


@pytest.mark.parametrize("payload, why", [
    (b"", "no header"), (b"\x01\x01\x00\x00" + bytes(48), "not CDR"), (CDR_LE + bytes(47), "short"),
    (CDR_LE + bytes(48) + bytes(4), "trailing"), (CDR_LE + struct.pack("<6d", math.nan, 0, 0, 0, 0, 0), "nan"),
    (CDR_LE + struct.pack("<6d", 0, 0, 0, 0, 0, math.inf), "inf"), (bytes(1 << 17), "too large"),
])
def test_bad_twists_are_refused(payload, why):
    with pytest.raises(ros2.Ros2Error):
        ros2.decode_twist(payload)


def test_bad_odometry_is_refused():
    good = ros2.encode_odometry(ros2.Odometry(0, 1.0, 2.0, 0.5, 0.0, 0.0))
    zero_q = bytearray(good)
    zero_q[40 + 4 + 24: 40 + 4 + 56] = bytes(32)  # orientation (x, y, z, w) = 0: no heading
    with pytest.raises(ros2.Ros2Error, match="heading"):
        ros2.decode_odometry(bytes(zero_q))
    nan_x = bytearray(good)
    nan_x[44:52] = struct.pack("<d", math.nan)
    with pytest.raises(ros2.Ros2Error, match="finite"):
        ros2.decode_odometry(bytes(nan_x))
    with pytest.raises(ros2.Ros2Error):
        ros2.decode_odometry(ros2.encode_twist(1.0, 0.0))  # a Twist is not an Odometry


@pytest.mark.parametrize("call", [
    lambda: ros2.encode_twist(math.nan, 0.0), lambda: ros2.encode_twist(0.0, math.inf),
    lambda: ros2.encode_twist_stamped(0.0, 0.0, -1), lambda: ros2.encode_twist_stamped(0.0, 0.0, 2**31 * 10**9),
    lambda: ros2.encode_odometry(ros2.Odometry(0, math.nan, 0.0, 0.0, 0.0, 0.0)),
])
def test_encoders_refuse_what_ros_could_not_carry(call):
    with pytest.raises(ros2.Ros2Error):
        call()


DECODERS = [ros2.decode_twist, ros2.decode_twist_stamped, ros2.decode_odometry, ros2.decode_attachment]


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(DECODERS), st.binary(max_size=800), st.booleans())
def test_decoders_raise_only_ros2_error_on_hostile_bytes(decode, data, with_header):
    payload = (CDR_LE + data) if with_header else data
    try:
        decode(payload)
    except ros2.Ros2Error:
        pass


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 3), st.data())
def test_decoders_survive_mutated_messages(which, data):
    """Real messages with a few bytes changed: decoded, or refused with Ros2Error, never anything else."""
    good = [ros2.encode_twist(0.1, 0.2), ros2.encode_twist_stamped(0.1, 0.2, 5),
            ros2.encode_odometry(ros2.Odometry(5, 1.0, 2.0, 0.3, 0.1, 0.2, "odom", "base_footprint")),
            ros2.encode_attachment(1, 2, bytes(16))][which]
    buf = bytearray(good)
    for _ in range(data.draw(st.integers(1, 4))):
        buf[data.draw(st.integers(0, len(buf) - 1))] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(buf)))
    try:
        DECODERS[which](bytes(buf[:cut]))
    except ros2.Ros2Error:
        pass


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet="@ros2_lv/%:,.MSPN0123456789abc*", max_size=120))
def test_parse_liveliness_never_raises(key):
    e = ros2.parse_liveliness(key)
    assert e is None or e.key == key


finite = st.floats(allow_nan=False, allow_infinity=False, width=64, min_value=-1e9, max_value=1e9)


@settings(max_examples=200, deadline=None)
@given(finite, finite, st.floats(-10.0, 10.0), finite, finite, st.integers(0, 2**31 * 10**9 - 1))
def test_messages_round_trip(x, y, yaw, v, w, stamp):
    assert ros2.decode_twist(ros2.encode_twist(v, w)) == (v, w)
    assert ros2.decode_twist_stamped(ros2.encode_twist_stamped(v, w, stamp)) == (v, w)
    o = ros2.decode_odometry(ros2.encode_odometry(ros2.Odometry(stamp, x, y, yaw, v, w)))
    assert (o.stamp_ns, o.x, o.y, o.v, o.w) == (stamp, x, y, v, w)
    assert abs(ros2.wrap(o.yaw - yaw)) < 1e-9


# --------------------------------------------------------------------------- planar frames


@pytest.mark.parametrize("yaw", [0.0, 0.3, -2.0, math.pi - 1e-9, 3.0, -3.1])
def test_yaw_and_quaternion(yaw):
    q = ros2.quaternion_of_yaw(yaw)
    assert math.isclose(sum(c * c for c in q), 1.0)
    assert ros2.yaw_of_quaternion(*q) == pytest.approx(yaw, abs=1e-12)
    assert ros2.yaw_of_quaternion(*(3.0 * c for c in q)) == pytest.approx(yaw, abs=1e-12)  # unnormalised


@pytest.mark.parametrize("q", [(0, 0, 0, 0), (0.0, 1.0, 0.0, 1.0), (math.nan, 0, 0, 1)])
def test_quaternions_without_a_heading_are_refused(q):
    with pytest.raises(ros2.Ros2Error):
        ros2.yaw_of_quaternion(*q)


def test_planar_frames_compose_and_invert():
    rng = np.random.default_rng(17)
    for _ in range(50):
        a = tuple(rng.uniform(-5, 5, 3))
        b = tuple(rng.uniform(-5, 5, 3))
        ident = ros2.se2_compose(a, ros2.se2_inverse(a))
        np.testing.assert_allclose(ident, (0.0, 0.0, 0.0), atol=1e-12)
        ab = ros2.se2_compose(a, b)
        np.testing.assert_allclose(ros2.se2_compose(ros2.se2_inverse(a), ab)[:2], b[:2], atol=1e-12)
    # a point 1 m ahead of a robot at (1, 2) facing +y is at (1, 3)
    np.testing.assert_allclose(ros2.se2_compose((1.0, 2.0, math.pi / 2), (1.0, 0.0, 0.0)),
                               (1.0, 3.0, math.pi / 2), atol=1e-12)


# --------------------------------------------------------------------------- without the extra


def test_the_module_loads_without_rosbags_and_names_the_extra(monkeypatch):
    for name in [m for m in sys.modules if m == "rosbags" or m.startswith("rosbags.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "rosbags", None)  # import rosbags... now fails
    spec = importlib.util.spec_from_file_location("ros2_without_rosbags", ros2.__file__)
    fresh = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "ros2_without_rosbags", fresh)  # dataclasses look their module up
    spec.loader.exec_module(fresh)
    assert fresh.bridge_key("robot1", "cmd_vel") == "robot1/cmd_vel"  # names need no rosbags
    assert fresh.parse_liveliness(SUB_TOKEN).node == "turtlebot3_node"
    with pytest.raises(ImportError, match=r"pip install 'swarm\[ros2\]'"):
        fresh.encode_twist(0.0, 0.0)
    with pytest.raises(ImportError, match=r"pip install 'swarm\[ros2\]'"):
        fresh.type_hash(fresh.TWIST)


def test_without_xxhash_the_extra_is_named_before_anything_starts(monkeypatch):
    """rosbags alone (the ros2 extra of before): require() names the extra, as every ROS 2 command calls it first."""
    monkeypatch.setitem(sys.modules, "xxhash", None)  # import xxhash... now fails
    with pytest.raises(ImportError, match=r"xxhash.*pip install 'swarm\[ros2\]'"):
        ros2.require()
    with pytest.raises(ImportError, match=r"xxhash.*pip install 'swarm\[ros2\]'"):
        ros2.entity_gid("@ros2_lv/0/x")

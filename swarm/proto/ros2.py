"""ROS 2 over zenoh without ROS: message bytes, keys, liveliness tokens and attachments (docs/ros2.md).

    ros2.rmw_key(0, "/robot1/cmd_vel", ros2.TWIST, ros2.type_hash(ros2.TWIST))
        -> "0/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45bf16..."
    ros2.bridge_key("robot1", "cmd_vel")               -> "robot1/cmd_vel"
    ros2.parse_liveliness("@ros2_lv/0/<zid>/0/11/MS/%/%robot1/turtlebot3_node/%robot1%cmd_vel/...")
        -> Entity(kind="MS", namespace="/robot1", node="turtlebot3_node", topic="/robot1/cmd_vel", ...)
    payload = ros2.encode_twist(0.2, -0.1)               # CDR, little-endian, with its 4-byte header
    v, w = ros2.decode_twist(payload)                    # Ros2Error on anything off
    att = ros2.encode_attachment(seq, time_ns, gid16)    # the 33 bytes rmw_zenoh's subscribers need

Two ways a ROS 2 robot meets zenoh. rmw_zenoh (the robot's nodes run on zenoh): a topic's data key
is `<domain>/<topic without its leading slash>/<DDS type name>/<type hash>`, the hash being RIHS01_<sha256>
on Jazzy and later and the literal TypeHashNotSupported on Humble; every sample must carry the
attachment (sequence number, source time, publisher gid) or the subscriber drops it; the graph is a
set of liveliness tokens under `@ros2_lv/<domain>/`. zenoh-bridge-ros2dds (the robot runs DDS and the
bridge): the key is the topic name without its leading slash, the payload the same CDR bytes, no
attachment, no hash.

Message bytes come from `rosbags` (its Jazzy type store; Humble's Twist, TwistStamped and Odometry
have the same layout), imported on first use so that this module loads without the `ros2` extra.
Type hashes are computed by rosbags from the message definitions, never written down here.
Decoders raise only Ros2Error, whatever the bytes. Pure: no zenoh, no I/O.
"""

from __future__ import annotations

import functools
import math
import re
import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING
from swarm.core.errors import SwarmError

if TYPE_CHECKING:
    from typing import Any

    from rosbags.typesys.store import Typestore

TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
NO_HASH = "TypeHashNotSupported"  # the hash chunk of Humble's rmw_zenoh keys
FLAVORS = ("rmw_zenoh", "bridge")
TWISTS = ("plain", "stamped")
CMD_VEL, ODOM = "cmd_vel", "odom"
LIVELINESS = "@ros2_lv"
ENTITY_KINDS = ("NN", "MP", "MS", "SS", "SC")  # node, publisher, subscription, service, client
MAX_PAYLOAD = 1 << 16  # bytes: an Odometry is 724 plus its frame names; anything larger is refused unread
ATTACHMENT_SIZE = 33
GID_SIZE = 16
INSTALL = "pip install 'swarm[ros2]'"

_NS = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")
_TOPIC = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")
_TYPENAME = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/msg/([A-Za-z][A-Za-z0-9_]*)$")
_DDS = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)::msg::dds_::([A-Za-z][A-Za-z0-9_]*)_$")
_ATTACHMENT = struct.Struct("<qqB16s")  # int64 seq, int64 source time [ns], sequence length 16, 16 gid bytes
# The attachment's two forms in the field (docs/ros2.md, Releases): "v2", the 33 bytes above (rmw_zenoh Rolling
# >= 0.6.0, Jazzy >= 0.2.4, Humble >= 0.1.2); "v1", each value after its name as a zenoh-ext string (rmw_zenoh
# Rolling before 0.6.0, Jazzy 0.2.0-0.2.3, Humble 0.1.0-0.1.1), 77 bytes. A subscriber of one form throws on the
# other's and drops the sample.
ATTACHMENT_FORMS = ("v1", "v2")
RELEASES = {"v1": "rmw_zenoh Rolling before 0.6.0, Jazzy 0.2.0-0.2.3 or Humble 0.1.0-0.1.1",
            "v2": "rmw_zenoh Rolling 0.6.0 or later, Jazzy 0.2.4 or later or Humble 0.1.2 or later"}
_V1_NAMES = (b"\x0fsequence_number", b"\x10source_timestamp", b"\x0asource_gid")  # LEB128 length, UTF-8
_V1 = struct.Struct(f"<{len(_V1_NAMES[0])}sq{len(_V1_NAMES[1])}sq{len(_V1_NAMES[2])}sB16s")
ATTACHMENT_SIZE_V1 = _V1.size
_INT64 = (-(1 << 63), (1 << 63) - 1)
_STAMP_MAX_NS = ((1 << 31) - 1) * 1_000_000_000 + 999_999_999  # builtin_interfaces/Time: int32 sec, uint32 nanosec


class Ros2Error(SwarmError, ValueError):
    """Bytes, a key or a value that is not what ROS 2 would send: the reason says what was wrong."""


# --------------------------------------------------------------------------- rosbags, lazily


@functools.cache
def typestore() -> Typestore:
    """rosbags' Jazzy type store (loaded once); ImportError naming the extra if rosbags is missing."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError as e:
        raise ImportError(f"ROS 2 messages need the rosbags package: {INSTALL}") from e
    return get_typestore(Stores.ROS2_JAZZY)


def require() -> None:
    """The ros2 extra is installed (rosbags for the messages, xxhash for rmw_zenoh's gids); ImportError naming it."""
    typestore()
    try:
        import xxhash  # noqa: F401
    except ImportError as e:
        raise ImportError(f"rmw_zenoh's gids need the xxhash package: {INSTALL}") from e


@functools.cache
def _types() -> dict[str, Any]:
    """The message classes this module builds, looked up once, and a zero covariance."""
    import numpy as np

    t = typestore().types
    names = {"Time": "builtin_interfaces/msg/Time", "Header": "std_msgs/msg/Header",
             "Vector3": "geometry_msgs/msg/Vector3", "Twist": TWIST, "TwistStamped": TWIST_STAMPED,
             "Point": "geometry_msgs/msg/Point", "Quaternion": "geometry_msgs/msg/Quaternion",
             "Pose": "geometry_msgs/msg/Pose", "PoseWithCovariance": "geometry_msgs/msg/PoseWithCovariance",
             "TwistWithCovariance": "geometry_msgs/msg/TwistWithCovariance", "Odometry": ODOMETRY}
    out: dict[str, Any] = {short: t[full] for short, full in names.items()}
    zero = np.zeros(36, dtype=np.float64)
    zero.flags.writeable = False
    out["zero36"] = zero
    return out


@functools.cache
def type_hash(typename: str) -> str:
    """The RIHS01 type hash of a ROS 2 message type (what Jazzy's rmw_zenoh puts in its keys)."""
    _split_type(typename)
    return typestore().hash_rihs01(typename)


# --------------------------------------------------------------------------- names and keys


def _split_type(typename: str) -> tuple[str, str]:
    m = _TYPENAME.match(typename) if isinstance(typename, str) else None
    if m is None:
        raise Ros2Error(f"a message type is package/msg/Name, got {typename!r}")
    return m.group(1), m.group(2)


def dds_type(typename: str) -> str:
    """geometry_msgs/msg/Twist -> geometry_msgs::msg::dds_::Twist_ (the type chunk of rmw_zenoh's keys)."""
    pkg, name = _split_type(typename)
    return f"{pkg}::msg::dds_::{name}_"


def ros_type(dds: str) -> str:
    """The inverse of dds_type; Ros2Error for anything else."""
    m = _DDS.match(dds) if isinstance(dds, str) else None
    if m is None:
        raise Ros2Error(f"not a DDS message type name: {dds!r}")
    return f"{m.group(1)}/msg/{m.group(2)}"


def twist_type(twist: str) -> str:
    """The cmd_vel message type of a --twist choice: plain -> Twist, stamped -> TwistStamped."""
    if twist == "plain":
        return TWIST
    if twist == "stamped":
        return TWIST_STAMPED
    raise Ros2Error(f"twist must be one of {', '.join(TWISTS)}, got {twist!r}")


def check_flavor(flavor: str) -> str:
    if flavor not in FLAVORS:
        raise Ros2Error(f"flavor must be one of {', '.join(FLAVORS)}, got {flavor!r}")
    return flavor


def check_domain(domain: int) -> int:
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain < 1 << 32:
        raise Ros2Error(f"a ROS 2 domain id is an int >= 0, got {domain!r}")
    return domain


def check_namespace(namespace: str) -> str:
    """A ROS namespace without its slashes: "/robot1" and "robot1/" -> "robot1"; "" or "/" -> "" (root)."""
    if not isinstance(namespace, str):
        raise Ros2Error(f"a namespace is a string, got {namespace!r}")
    ns = namespace.strip("/")
    if ns and not _NS.match(ns):
        raise Ros2Error(f"a ROS namespace is names of letters, digits and '_' (not starting with a digit) "
                        f"separated by '/', got {namespace!r}")
    return ns


def topic_name(namespace: str, topic: str) -> str:
    """The fully qualified topic: ("robot1", "cmd_vel") -> "/robot1/cmd_vel"; ("", "odom") -> "/odom"."""
    ns = check_namespace(namespace)
    if not isinstance(topic, str) or not _TOPIC.match(topic.strip("/")):
        raise Ros2Error(f"not a ROS topic name: {topic!r}")
    return f"/{ns}/{topic.strip('/')}" if ns else f"/{topic.strip('/')}"


def _check_hash(h: str) -> str:
    if not isinstance(h, str) or not (h == NO_HASH or re.fullmatch(r"RIHS01_[0-9a-f]{64}", h)):
        raise Ros2Error(f"a type hash is RIHS01_<64 hex digits> or {NO_HASH}, got {h!r}")
    return h


def rmw_key(domain: int, topic: str, typename: str, hash_: str) -> str:
    """rmw_zenoh's data key of a topic: <domain>/<topic without its leading slash>/<DDS type>/<hash>."""
    name = topic.strip("/") if isinstance(topic, str) else ""
    if not name or not _TOPIC.match(name):
        raise Ros2Error(f"not a ROS topic name: {topic!r}")
    return f"{check_domain(domain)}/{name}/{dds_type(typename)}/{_check_hash(hash_)}"


def bridge_key(namespace: str, topic: str) -> str:
    """zenoh-bridge-ros2dds's key of a topic: the ROS name without its leading slash ("robot1/cmd_vel")."""
    return topic_name(namespace, topic)[1:]


def doubled_bridge_key(namespace: str, topic: str) -> str | None:
    """Where a topic of a robot in `namespace` lands behind a bridge started with that namespace too (`-n /robot1`
    in front of the robot's own /robot1/cmd_vel: "robot1/robot1/cmd_vel"); None without a namespace."""
    ns = check_namespace(namespace)
    return f"{ns}/{bridge_key(ns, topic)}" if ns else None


def liveliness_any(domain: int) -> str:
    """Every liveliness token of a domain. `@ros2_lv` is a verbatim chunk in zenoh: `**` alone never
    matches it, so a watcher must name it."""
    return f"{LIVELINESS}/{check_domain(domain)}/**"


def qos_string(depth: int = 10, reliable: bool = True, transient_local: bool = False) -> str:
    """The QoS chunk of a liveliness token as rmw_zenoh writes it, for a keep-last history:
    `reliability:durability:history,depth:deadline:lifespan:liveliness`, each field the rmw enum value or number
    only where it differs from rmw's default profile (reliable, volatile, keep last, depth 10, no deadline, lifespan
    or liveliness lease), empty where it equals it: a TurtleBot3's cmd_vel subscription (reliable, volatile, keep
    last 10) is `::,:,:,:,,`. (Reliability 2 is best effort, durability 1 transient local.)"""
    return f"{'' if reliable else 2}:{1 if transient_local else ''}:,{'' if int(depth) == 10 else int(depth)}:,:,:,,"


def _mangle(name: str) -> str:
    return name.replace("/", "%")


def _demangle(chunk: str) -> str:
    return chunk.replace("%", "/")


@dataclass(frozen=True)
class Entity:
    """One rmw_zenoh graph entity, as its liveliness token tells it (names are demangled: namespace
    "/robot1", topic "/robot1/cmd_vel"; dds_type as in the data key). A node (NN) has no topic."""

    domain: int
    zid: str  # the zenoh session's id (hex)
    nid: str  # the node's id within the session
    eid: str  # the entity's id within the session
    kind: str  # NN, MP, MS, SS, SC
    enclave: str  # "/" by default
    namespace: str  # "/" for the root namespace
    node: str
    topic: str | None = None
    dds_type: str | None = None
    type_hash: str | None = None
    qos: str | None = None

    @property
    def data_key(self) -> str:
        """The data key of its topic (the key a publisher puts on and a subscriber listens to)."""
        if self.topic is None:
            raise Ros2Error(f"a {self.kind} entity has no topic")
        return f"{self.domain}/{self.topic.strip('/')}/{self.dds_type}/{self.type_hash}"

    @property
    def key(self) -> str:
        """Its liveliness token's key (what parse_liveliness reads back)."""
        parts = [LIVELINESS, str(check_domain(self.domain)), self.zid, self.nid, self.eid, self.kind,
                 _mangle(self.enclave), _mangle(self.namespace), _mangle(self.node)]
        if self.topic is not None:
            parts += [_mangle(self.topic), self.dds_type or "", self.type_hash or "", self.qos or ""]
        key = "/".join(parts)
        if parse_liveliness(key) != self:
            raise Ros2Error(f"not a valid liveliness token: {self!r}")
        return key


_CHUNK = re.compile(r"^[^/*$?#]+$")


def parse_liveliness(key: str) -> Entity | None:
    """An rmw_zenoh liveliness token's key -> Entity; None for anything that is not one:
    @ros2_lv/<domain>/<zid>/<nid>/<eid>/<kind>/<enclave>/<namespace>/<node>[/<topic>/<type>/<hash>/<qos>]
    with '/' inside names written as '%'."""
    if not isinstance(key, str):
        return None
    parts = key.split("/")
    if len(parts) not in (9, 13) or parts[0] != LIVELINESS or not all(_CHUNK.match(p) for p in parts[1:]):
        return None
    domain, zid, nid, eid, kind, enclave, ns, node = parts[1:9]
    if not domain.isascii() or not domain.isdigit() or len(domain) > 10 or kind not in ENTITY_KINDS:
        return None
    topic_parts = parts[9:]
    if (kind == "NN") != (not topic_parts):
        return None
    topic = dds = hash_ = qos = None
    if topic_parts:
        topic, dds, hash_, qos = _demangle(topic_parts[0]), topic_parts[1], topic_parts[2], topic_parts[3]
    return Entity(int(domain), zid, nid, eid, kind, _demangle(enclave), _demangle(ns), _demangle(node),
                  topic, dds, hash_, qos)


def entity_gid(token: str) -> bytes:
    """rmw_zenoh's gid of a graph entity: the XXH3-128 hash of its liveliness token's key, its low 64 bits then its
    high 64 bits, each little-endian (what `ros2 topic info -v` shows, and what the entity's samples carry in
    their attachment). ImportError naming the extra if xxhash is missing."""
    try:
        import xxhash
    except ImportError as e:
        raise ImportError(f"rmw_zenoh's gids need the xxhash package: {INSTALL}") from e
    h = xxhash.xxh3_128_intdigest(token.encode())
    return (h & 0xFFFF_FFFF_FFFF_FFFF).to_bytes(8, "little") + (h >> 64).to_bytes(8, "little")


# --------------------------------------------------------------------------- zenoh-bridge-ros2dds's routes

BRIDGE_SLASH = "\u00a7"  # the bridge writes '/' inside a chunk of its route tokens as the section sign
BRIDGE_ROUTE_KINDS = ("MP", "MS")  # a route for a ROS 2 publisher (data out of the robot), for a subscriber (in)
BRIDGE_QOS = ":1:0:0,10"  # keyless, reliable, volatile, keep last 10 (a TurtleBot3's cmd_vel and odom)


@dataclass(frozen=True)
class BridgeRoute:
    """One route zenoh-bridge-ros2dds announces with a liveliness token while a ROS 2 node behind it publishes
    (MP) or subscribes (MS) a topic, with '/' inside the key and the type written as BRIDGE_SLASH:
    `@/<bridge zid>/@ros2_lv/<kind>/<zenoh key>/<ROS 2 type>/<qos>` since the bridge's 1.0 (the releases that
    speak zenoh 1.x, as swarm does), `@ros2_lv/<bridge zid>/<kind>/...` before (`legacy`). It is how another
    bridge learns the message type of a topic; swarm reads it to check the robot's cmd_vel type (docs/ros2.md,
    The bridge's routes)."""

    zid: str
    kind: str  # MP or MS
    key: str  # the zenoh key the data goes on: "robot1/cmd_vel"
    ros2_type: str  # "geometry_msgs/msg/TwistStamped"
    qos: str = BRIDGE_QOS
    legacy: bool = False  # the 0.x form

    @property
    def token(self) -> str:
        """Its liveliness token's key (what parse_bridge_route reads back)."""
        esc = BRIDGE_SLASH
        head = f"{LIVELINESS}/{self.zid}" if self.legacy else f"@/{self.zid}/{LIVELINESS}"
        key = f"{head}/{self.kind}/{self.key.replace('/', esc)}/{self.ros2_type.replace('/', esc)}/{self.qos}"
        if parse_bridge_route(key) != self:
            raise Ros2Error(f"not a valid bridge route: {self!r}")
        return key


def bridge_routes(kind: str) -> tuple[str, str]:
    """The key expressions of every route of one kind (MP or MS) of every bridge: the 1.x form, the 0.x form."""
    if kind not in BRIDGE_ROUTE_KINDS:
        raise Ros2Error(f"a bridge route's kind is one of {', '.join(BRIDGE_ROUTE_KINDS)}, got {kind!r}")
    return f"@/*/{LIVELINESS}/{kind}/*/*/*", f"{LIVELINESS}/*/{kind}/*/*/*"


def parse_bridge_route(key: str) -> BridgeRoute | None:
    """A bridge's route token (either form) -> BridgeRoute; None for anything that is not one (an rmw_zenoh token
    has a domain number where a 0.x bridge has its zenoh id, and its kind further on)."""
    if not isinstance(key, str):
        return None
    parts = key.split("/")
    if len(parts) == 7 and parts[0] == "@" and parts[2] == LIVELINESS:
        legacy, rest = False, [parts[1], *parts[3:]]
    elif len(parts) == 6 and parts[0] == LIVELINESS:
        legacy, rest = True, parts[1:]
    else:
        return None
    if not all(_CHUNK.match(p) for p in rest):
        return None
    zid, kind, zkey, typ, qos = rest
    if kind not in BRIDGE_ROUTE_KINDS:
        return None
    zkey, typ = zkey.replace(BRIDGE_SLASH, "/"), typ.replace(BRIDGE_SLASH, "/")
    if not _TOPIC.match(zkey) or not _TYPENAME.match(typ):
        return None
    return BridgeRoute(zid, kind, zkey, typ, qos, legacy)


BRIDGE_ADMIN_SUB = "@/*/ros2/route/topic/sub"  # + "/<zenoh key>": a bridge's admin space, a route to a ROS 2 subscriber
MAX_ADMIN_REPLY = 1 << 16  # bytes: a route's JSON is a few hundred; anything larger is not read


def bridge_admin_type(payload: bytes) -> str | None:
    """The ROS 2 type of a route as zenoh-bridge-ros2dds's admin space gives it (a JSON object with `ros2_type`,
    e.g. `{"ros2_name": "/robot1/cmd_vel", "ros2_type": "geometry_msgs/msg/TwistStamped", "is_active": true, ...}`);
    None for a route that is not active (no local node behind it) and for anything else, whatever the bytes."""
    import json

    if not isinstance(payload, (bytes, bytearray)) or len(payload) > MAX_ADMIN_REPLY:
        return None
    try:
        doc = json.loads(bytes(payload).decode("utf-8"))
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    if not isinstance(doc, dict) or doc.get("is_active") is False:  # a route made for a remote bridge's only
        return None
    typ = doc.get("ros2_type")
    return typ if isinstance(typ, str) and _TYPENAME.match(typ) else None


def twist_of(typename: str) -> str | None:
    """The --twist choice of a cmd_vel type (ROS 2 or DDS name): Twist -> "plain", TwistStamped -> "stamped"; None
    for any other type."""
    for twist in TWISTS:
        if typename in (twist_type(twist), dds_type(twist_type(twist))):
            return twist
    return None


# --------------------------------------------------------------------------- attachment


@dataclass(frozen=True)
class Attachment:
    """rmw_zenoh's per-sample attachment: the publisher's sequence number, the source time [ns since
    the Unix epoch] and the publisher's 16-byte gid."""

    seq: int
    timestamp_ns: int
    gid: bytes


def check_attachment_form(form: str) -> str:
    if form not in ATTACHMENT_FORMS:
        raise ValueError(f"an attachment form is one of {', '.join(ATTACHMENT_FORMS)}, got {form!r}")
    return form


def encode_attachment(seq: int, timestamp_ns: int, gid: bytes, form: str = "v2") -> bytes:
    """v2: the 33 bytes in zenoh-ext serializer form: int64 LE seq, int64 LE time [ns], then the gid as a
    sequence: its length 16 (one LEB128 byte, 0x10) and the 16 bytes. v1: the same values, each after its name
    as a zenoh-ext string ("sequence_number", "source_timestamp", "source_gid"), 77 bytes."""
    for name, x in (("seq", seq), ("timestamp_ns", timestamp_ns)):
        if isinstance(x, bool) or not isinstance(x, int) or not _INT64[0] <= x <= _INT64[1]:
            raise Ros2Error(f"{name} must be an int64, got {x!r}")
    if not isinstance(gid, (bytes, bytearray)) or len(gid) != GID_SIZE:
        raise Ros2Error(f"a gid is {GID_SIZE} bytes, got {gid!r}")
    if check_attachment_form(form) == "v1":
        return _V1.pack(_V1_NAMES[0], seq, _V1_NAMES[1], timestamp_ns, _V1_NAMES[2], GID_SIZE, bytes(gid))
    return _ATTACHMENT.pack(seq, timestamp_ns, GID_SIZE, bytes(gid))


def decode_attachment(data: bytes | None, form: str = "v2") -> Attachment:
    """The inverse of encode_attachment for that form; Ros2Error for anything else (as that form's rmw_zenoh
    subscriber throws and drops the sample)."""
    if data is None:
        raise Ros2Error("no attachment (rmw_zenoh drops such a sample)")
    size = ATTACHMENT_SIZE_V1 if check_attachment_form(form) == "v1" else ATTACHMENT_SIZE
    if not isinstance(data, (bytes, bytearray, memoryview)) or len(data) != size:
        got = len(data) if isinstance(data, (bytes, bytearray, memoryview)) else type(data).__name__
        raise Ros2Error(f"a {form} attachment is {size} bytes, got {got}")
    if form == "v1":
        k1, seq, k2, ts, k3, n, gid = _V1.unpack(bytes(data))
        for got_name, want in ((k1, _V1_NAMES[0]), (k2, _V1_NAMES[1]), (k3, _V1_NAMES[2])):
            if got_name != want:
                raise Ros2Error(f"a v1 attachment names {want[1:].decode()} there, got {got_name[1:]!r}")
    else:
        seq, ts, n, gid = _ATTACHMENT.unpack(bytes(data))
    if n != GID_SIZE:
        raise Ros2Error(f"the attachment's gid must be a sequence of {GID_SIZE} bytes, its length says {n}")
    return Attachment(seq, ts, gid)


def attachment_form(data: bytes | None) -> str | None:
    """The form of an rmw_zenoh attachment ("v1" or "v2", ATTACHMENT_FORMS), None when it is neither: what a
    robot's own samples say of its rmw_zenoh release."""
    for form in ATTACHMENT_FORMS:
        try:
            decode_attachment(data, form)
        except Ros2Error:
            continue
        return form
    return None


# --------------------------------------------------------------------------- messages


@dataclass(frozen=True)
class Odometry:
    """The planar content of a nav_msgs/msg/Odometry: the pose of child_frame_id in frame_id (x, y [m],
    yaw [rad]; z, roll and pitch are 0 when written and ignored when read) and its velocity in
    child_frame_id (v = linear.x [m/s], w = angular.z [rad/s]); stamp_ns = header.stamp [ns]."""

    stamp_ns: int
    x: float
    y: float
    yaw: float
    v: float
    w: float
    frame_id: str = "odom"
    child_frame_id: str = "base_footprint"


def seconds_to_ns(seconds: float) -> int:
    """Seconds (a float) -> integer nanoseconds, rounded, for a header stamp."""
    if not math.isfinite(seconds):
        raise Ros2Error(f"a stamp must be finite, got {seconds}")
    return round(seconds * 1e9)


def _time(ns: int) -> object:
    if isinstance(ns, bool) or not isinstance(ns, int) or not 0 <= ns <= _STAMP_MAX_NS:
        raise Ros2Error(f"a stamp is an int of ns in [0, {_STAMP_MAX_NS}], got {ns!r}")
    sec, nanosec = divmod(ns, 1_000_000_000)
    return _types()["Time"](sec=sec, nanosec=nanosec)


def _finite(**values: float) -> None:
    for name, x in values.items():
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise Ros2Error(f"{name} must be a finite number, got {x!r}")


def _serialize(msg: object, typename: str) -> bytes:
    return bytes(typestore().serialize_cdr(msg, typename, little_endian=True))


def _twist(v: float, w: float) -> object:
    T = _types()
    return T["Twist"](linear=T["Vector3"](x=float(v), y=0.0, z=0.0), angular=T["Vector3"](x=0.0, y=0.0, z=float(w)))


def encode_twist(v: float, w: float) -> bytes:
    """geometry_msgs/msg/Twist with linear.x = v [m/s], angular.z = w [rad/s], the rest 0 (52 bytes)."""
    _finite(v=v, w=w)
    return _serialize(_twist(v, w), TWIST)


def encode_twist_stamped(v: float, w: float, stamp_ns: int, frame_id: str = "base_link") -> bytes:
    """geometry_msgs/msg/TwistStamped: header (stamp_ns [ns since the epoch], frame_id) and the twist of
    encode_twist."""
    _finite(v=v, w=w)
    T = _types()
    msg = T["TwistStamped"](header=T["Header"](stamp=_time(stamp_ns), frame_id=str(frame_id)), twist=_twist(v, w))
    return _serialize(msg, TWIST_STAMPED)


def encode_odometry(o: Odometry) -> bytes:
    """nav_msgs/msg/Odometry of `o`: orientation the quaternion of yaw, covariances 0."""
    _finite(x=o.x, y=o.y, yaw=o.yaw, v=o.v, w=o.w)
    T = _types()
    qx, qy, qz, qw = quaternion_of_yaw(o.yaw)
    pose = T["Pose"](position=T["Point"](x=float(o.x), y=float(o.y), z=0.0),
                     orientation=T["Quaternion"](x=qx, y=qy, z=qz, w=qw))
    msg = T["Odometry"](header=T["Header"](stamp=_time(o.stamp_ns), frame_id=str(o.frame_id)),
                        child_frame_id=str(o.child_frame_id),
                        pose=T["PoseWithCovariance"](pose=pose, covariance=T["zero36"]),
                        twist=T["TwistWithCovariance"](twist=_twist(o.v, o.w), covariance=T["zero36"]))
    return _serialize(msg, ODOMETRY)


def _deserialize(payload: bytes, typename: str) -> Any:
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise Ros2Error(f"a payload is bytes, got {type(payload).__name__}")
    if len(payload) > MAX_PAYLOAD:
        raise Ros2Error(f"a {typename} of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    data = bytes(payload)
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise Ros2Error(f"not CDR: the header is {data[:4].hex() or 'missing'}, not 00 01 00 00 (or 00 00, big-endian)")
    store = typestore()
    try:
        msgdef = store.get_msgdef(typename)
        fn = msgdef.deserialize_cdr_le if data[1] else msgdef.deserialize_cdr_be
        msg, pos = fn(memoryview(data)[4:], 0, msgdef.cls, store)
    except Exception as e:  # rosbags raises struct.error, IndexError, UnicodeDecodeError... on garbage
        raise Ros2Error(f"not a {typename}: {type(e).__name__}: {e}"[:200]) from None
    end = 4 + pos
    if not len(data) - 3 <= end <= len(data):  # what it read must be the message, up to 3 bytes of padding
        raise Ros2Error(f"a {typename} of {end} bytes in a payload of {len(data)}")
    return msg


def _vw(twist: Any) -> tuple[float, float]:
    v, w = float(twist.linear.x), float(twist.angular.z)
    _finite(v=v, w=w)
    return v, w


def decode_twist(payload: bytes) -> tuple[float, float]:
    """A geometry_msgs/msg/Twist -> (v, w) = (linear.x [m/s], angular.z [rad/s]) (a differential drive
    has no other velocity); Ros2Error for anything else or non-finite values."""
    return _vw(_deserialize(payload, TWIST))


def decode_twist_stamped(payload: bytes) -> tuple[float, float]:
    """A geometry_msgs/msg/TwistStamped -> (v, w) as decode_twist (the header is not used)."""
    return _vw(_deserialize(payload, TWIST_STAMPED).twist)


def decode_odometry(payload: bytes) -> Odometry:
    """A nav_msgs/msg/Odometry -> Odometry (yaw from the orientation); Ros2Error for anything else,
    non-finite values or an orientation with no planar heading (a zero quaternion)."""
    m = _deserialize(payload, ODOMETRY)
    p, q, tw = m.pose.pose.position, m.pose.pose.orientation, m.twist.twist
    x, y = float(p.x), float(p.y)
    _finite(x=x, y=y)
    yaw = yaw_of_quaternion(float(q.x), float(q.y), float(q.z), float(q.w))
    v, w = _vw(tw)
    stamp = int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)
    return Odometry(stamp, x, y, yaw, v, w, m.header.frame_id, m.child_frame_id)


# --------------------------------------------------------------------------- planar frames


def quaternion_of_yaw(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by yaw [rad] about z."""
    return 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def yaw_of_quaternion(x: float, y: float, z: float, w: float) -> float:
    """The heading [rad, (-pi, pi]] of the x axis rotated by quaternion (x, y, z, w), unnormalised
    allowed; Ros2Error if it is not finite or leaves the x axis vertical (no heading)."""
    _finite(qx=x, qy=y, qz=z, qw=w)
    s = 2.0 * (w * z + x * y)
    c = w * w + x * x - y * y - z * z
    n = w * w + x * x + y * y + z * z
    if not n > 0.0 or math.hypot(s, c) <= 1e-9 * n:
        raise Ros2Error(f"quaternion ({x}, {y}, {z}, {w}) gives no heading")
    return math.atan2(s, c)


def wrap(a: float) -> float:
    """An angle in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


def se2_compose(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """a * b: the pose b, given in frame a, expressed in a's parent frame. Poses are (x [m], y [m], theta [rad])."""
    ax, ay, ath = a
    c, s = math.cos(ath), math.sin(ath)
    return ax + c * b[0] - s * b[1], ay + s * b[0] + c * b[1], wrap(ath + b[2])


def se2_inverse(a: tuple[float, float, float]) -> tuple[float, float, float]:
    """a^-1, so that se2_compose(a, se2_inverse(a)) is the identity."""
    ax, ay, ath = a
    c, s = math.cos(ath), math.sin(ath)
    return -(c * ax + s * ay), s * ax - c * ay, wrap(-ath)

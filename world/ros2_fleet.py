"""A simulated ROS 2 fleet: the world's unicycles as TurtleBot3-like ROS 2 robots on zenoh (docs/ros2.md).

    fleet = Ros2Fleet(bus, starts=[(x0, y0, th0), ...], flavor="rmw_zenoh", twist="plain")
    fleet.start()                          # subscribe every robot's cmd_vel; rmw_zenoh: announce the graph
    for i, v, w in fleet.take_commands():  # on the world's loop thread, in arrival order
        ...                                # robot i now holds (v, w)
    fleet.publish_odom(i, t, x, y, theta, v, w)   # robot i's world pose -> Odometry in its own odom frame
    fleet.close()

Robot i is a ROS 2 node `turtlebot3_node` in namespace `/robot<i>` (or namespace(i)), subscribing
`/robot<i>/cmd_vel` (geometry_msgs/msg/Twist, or TwistStamped with twist="stamped") and publishing
`/robot<i>/odom` (nav_msgs/msg/Odometry, frame `odom`, child `base_footprint`), both keep-last 10,
reliable, volatile, as the TurtleBot3 bringup declares them. Its odometry starts at zero where the
robot starts (odom frame = its start pose), as a real robot's does, so a drive must anchor it.

rmw_zenoh flavour: the data keys are rmw_zenoh's (`<domain>/robot<i>/cmd_vel/<DDS type>/<hash>`, the
hash computed by rosbags, or TypeHashNotSupported with distro="humble"); each robot announces its node,
subscription and publication as rmw_zenoh liveliness tokens (one zenoh id per robot, as one process per
robot would have); a command without a valid 33-byte attachment is dropped and counted
(`dropped_no_attachment`), as rmw_zenoh's subscriber drops it; odometry goes out with an attachment.
bridge flavour (zenoh-bridge-ros2dds): keys `robot<i>/cmd_vel` and `robot<i>/odom`, no attachment; each robot's
bridge announces its two routes with their ROS 2 types (`@ros2_lv/<zid>/MS/robot<i>§cmd_vel/...`), as the bridge does.

Commands wait in a queue filled on the bus's thread (the callback only appends) and are decoded on the
caller's thread by take_commands(): the world's loop never waits for zenoh, zenoh never waits for it.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from typing import TYPE_CHECKING, Callable, cast

from swarm.proto import protocol, ros2
from swarm.proto.ros2 import Entity, Odometry, Ros2Error

if TYPE_CHECKING:
    from collections.abc import Sequence
    from typing import Any

log = logging.getLogger("swarm.world.ros2")

NODE = "turtlebot3_node"
QOS_DEPTH = 10
DISTROS = ("jazzy", "humble", "rolling")  # rolling writes its keys and tokens as jazzy does


def default_namespace(i: int) -> str:
    return f"robot{i}"


class Ros2Fleet:
    def __init__(self, bus, starts: Sequence[Sequence[float]], flavor: str, twist: str, domain: int = 0,
                 namespace: Callable[[int], str] = default_namespace, distro: str = "jazzy",
                 queue_depth: int | None = None, wall_ns: Callable[[], int] = time.time_ns,
                 attachment: str = "v2") -> None:
        """starts: (N, 3) each robot's start pose in the world [m, m, rad] (its odom frame's origin);
        distro "humble" writes TypeHashNotSupported in keys and tokens instead of RIHS01 hashes;
        wall_ns: the publishers' clock for the attachments' source time [ns since the epoch];
        attachment: the rmw_zenoh release's attachment form (ros2.ATTACHMENT_FORMS): its odometry carries it, and a
        command with the other form is dropped, as that release's subscriber does."""
        self.bus, self.wall_ns = bus, wall_ns
        self.attachment = ros2.check_attachment_form(attachment)
        self.flavor = ros2.check_flavor(flavor)
        self.cmd_type = ros2.twist_type(twist)
        self.domain = ros2.check_domain(domain)
        if distro not in DISTROS:
            raise ValueError(f"distro must be one of {', '.join(DISTROS)}, got {distro!r}")
        self.distro = distro
        self.starts = [tuple(float(a) for a in s) for s in starts]
        if any(len(s) != 3 or not all(math.isfinite(a) for a in s) for s in self.starts):
            raise ValueError("starts must be (x, y, theta) triples of finite numbers")
        self.n = len(self.starts)
        self.namespaces = [ros2.check_namespace(namespace(i)) for i in range(self.n)]
        if len(set(self.namespaces)) != self.n:
            raise ValueError(f"robots need distinct namespaces, got {self.namespaces}")
        triples = cast("list[tuple[float, float, float]]", self.starts)  # each of length 3 (checked above)
        self._from_world = [ros2.se2_inverse(s) for s in triples]  # world frame -> robot i's odom frame
        ros2.require()  # fail now, naming the extra, if rosbags or xxhash is missing
        self.cmd_keys = [self._key(ns, ros2.CMD_VEL, self.cmd_type) for ns in self.namespaces]
        self.odom_keys = [self._key(ns, ros2.ODOM, ros2.ODOMETRY) for ns in self.namespaces]
        self._robot_of = {k: i for i, k in enumerate(self.cmd_keys)}
        self._zids = [os.urandom(16).hex() for _ in range(self.n)]
        # each odom publisher's gid: rmw_zenoh's, from its token (the bridge carries none)
        self._gids = [ros2.entity_gid(self.entities(i)[2].key) if self.flavor == "rmw_zenoh" else bytes(ros2.GID_SIZE)
                      for i in range(self.n)]
        self._odom_seq = [0] * self.n
        self._queue: deque[tuple[int, str, bytes, bytes | None]] = deque(maxlen=queue_depth or 64 * self.n + 64)
        self._lock = threading.Lock()  # publish_odom's sequence numbers
        self._handles: list = []
        self.bad = protocol.BadMessages(log)  # undecodable cmd_vel payloads
        self.dropped_no_attachment = 0  # rmw_zenoh: commands without a valid attachment
        self.commands = 0  # commands taken

    def _key(self, ns: str, topic: str, typename: str) -> str:
        if self.flavor == "bridge":
            return ros2.bridge_key(ns, topic)
        h = ros2.NO_HASH if self.distro == "humble" else ros2.type_hash(typename)
        return ros2.rmw_key(self.domain, ros2.topic_name(ns, topic), typename, h)

    def entities(self, i: int) -> list[Entity]:
        """Robot i's rmw_zenoh graph: its node, its cmd_vel subscription, its odom publication."""
        ns = "/" + self.namespaces[i] if self.namespaces[i] else "/"
        qos = ros2.qos_string(QOS_DEPTH)
        common: dict[str, Any] = dict(domain=self.domain, zid=self._zids[i], nid="0", enclave="/", namespace=ns,
                                      node=NODE)
        cmd, odom = self.cmd_keys[i].split("/"), self.odom_keys[i].split("/")
        return [Entity(eid="0", kind="NN", **common),
                Entity(eid="1", kind="MS", topic=ros2.topic_name(self.namespaces[i], ros2.CMD_VEL),
                       dds_type=cmd[-2], type_hash=cmd[-1], qos=qos, **common),
                Entity(eid="2", kind="MP", topic=ros2.topic_name(self.namespaces[i], ros2.ODOM),
                       dds_type=odom[-2], type_hash=odom[-1], qos=qos, **common)]

    def routes(self, i: int) -> list[ros2.BridgeRoute]:
        """Robot i's bridge routes (bridge flavour): its cmd_vel subscription and its odom publication, announced
        by its own bridge (one zenoh id per robot)."""
        return [ros2.BridgeRoute(self._zids[i], "MS", self.cmd_keys[i], self.cmd_type),
                ros2.BridgeRoute(self._zids[i], "MP", self.odom_keys[i], ros2.ODOMETRY)]

    def start(self) -> None:
        """Subscribe every robot's cmd_vel (with attachments), then declare each robot's tokens, as a ROS 2 node
        does (whoever sees the token can send): rmw_zenoh's graph, or the bridge's routes."""
        q = self._queue
        for i, key in enumerate(self.cmd_keys):
            self._handles.append(self.bus.subscribe_raw(key, lambda k, p, a, i=i: q.append((i, k, p, a))))
            tokens = [e.key for e in self.entities(i)] if self.flavor == "rmw_zenoh" else \
                [r.token for r in self.routes(i)]
            for token in tokens:
                self._handles.append(self.bus.token(token))
        log.info("simulated ROS 2 fleet: %d robots, %s (%s attachments), cmd_vel as %s, first keys %s and %s", self.n,
                 self.flavor, self.attachment, self.cmd_type, self.cmd_keys[0] if self.n else "-",
                 self.odom_keys[0] if self.n else "-")

    def take_commands(self) -> list[tuple[int, float, float]]:
        """(robot, v [m/s], w [rad/s]) of every command received since the last call, in arrival order.
        rmw_zenoh: a command without a valid attachment is dropped (dropped_no_attachment); an
        undecodable one is dropped and counted in `bad`."""
        out = []
        q = self._queue
        while q:
            i, key, payload, att = q.popleft()
            if self.flavor == "rmw_zenoh":
                try:
                    ros2.decode_attachment(att, self.attachment)
                except Ros2Error as e:
                    self.dropped_no_attachment += 1
                    if self.dropped_no_attachment == 1:
                        log.warning("dropped a command on %s: %s (rmw_zenoh drops these silently)", key, e)
                    continue
            try:
                if self.cmd_type == ros2.TWIST:
                    v, w = ros2.decode_twist(payload)
                else:
                    v, w = ros2.decode_twist_stamped(payload)
            except Ros2Error as e:
                self.bad.reject(key, e)
                continue
            out.append((i, v, w))
        self.commands += len(out)
        return out

    def publish_odom(self, i: int, t: float, x: float, y: float, theta: float, v: float, w: float) -> None:
        """Robot i's world pose (x, y [m], theta [rad]) and velocity (v [m/s], w [rad/s]) at simulated
        time t [s] as its Odometry: the pose in its odom frame (its start pose is the origin), stamped t."""
        ox, oy, oth = ros2.se2_compose(self._from_world[i], (x, y, theta))
        stamp = ros2.seconds_to_ns(max(0.0, t))  # the header carries the simulated time (a robot's use_sim_time)
        payload = ros2.encode_odometry(Odometry(stamp_ns=stamp, x=ox, y=oy, yaw=oth, v=v, w=w))
        # reliable=False: congestion control DROP, as rmw_zenoh puts a keep-last publisher's samples (BLOCK only
        # for keep-all reliable ones): a subscriber that stopped reading (a router that left with its link not
        # yet closed) never stalls the fleet's loop (docs/ros2.md)
        if self.flavor == "bridge":
            self.bus.put(self.odom_keys[i], payload, reliable=False)
            return
        with self._lock:
            self._odom_seq[i] += 1
            seq = self._odom_seq[i]
        att = ros2.encode_attachment(seq, self.wall_ns(), self._gids[i], self.attachment)
        self.bus.put(self.odom_keys[i], payload, reliable=False, attachment=att)

    def close(self) -> None:
        for h in reversed(self._handles):
            h.close()
        self._handles.clear()

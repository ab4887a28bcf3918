"""The ROS 2 drive in the robot's ROS 2 graph, as rmw_zenoh's liveliness tokens show it: finding the robot's cmd_vel
subscriber and odom publisher (or saying what was seen instead), and the entities the drive announces itself as."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

from swarm.core.errors import SwarmError
from swarm.proto import ros2
from swarm.proto.ros2 import Entity

NODE = "swarm_drive"  # the ROS 2 node name the drive announces in the robot's namespace
QOS_DEPTH = 10


class DiscoveryError(SwarmError, RuntimeError):
    """The robot's ROS 2 topics were not found in time; the message says what was seen."""


@dataclass(frozen=True)
class Discovery:
    """What a Ros2Drive looks for (its attributes of the same names): the robot's topics in its namespace and
    domain, the command type (twist_given auto: either), and how long it waits."""

    bus: Any
    namespace: str
    domain: int
    cmd_topic: str
    odom_topic: str
    cmd_type: str
    twist_given: str
    discover_timeout_s: float

    def find(self) -> tuple[Entity, Entity]:
        """The robot's cmd_vel subscription (MS, of the command type; twist auto: of either) and odom publication
        (MP, Odometry) in this namespace and domain, from the liveliness tokens (DiscoveryError after
        discover_timeout_s)."""
        want_odom = ros2.dds_type(ros2.ODOMETRY)
        want_cmd = {ros2.dds_type(ros2.twist_type(t)) for t in ros2.TWISTS} if self.twist_given == "auto" \
            else {ros2.dds_type(self.cmd_type)}
        seen: dict[str, Entity] = {}
        cond = threading.Condition()

        def on(key: str, alive: bool) -> None:
            e = ros2.parse_liveliness(key)
            if e is None:
                return
            with cond:
                if alive:
                    seen[key] = e
                else:
                    seen.pop(key, None)
                cond.notify_all()

        def found() -> tuple[Entity, Entity] | None:
            sub = [e for e in seen.values() if e.kind == "MS" and e.topic == self.cmd_topic and e.dds_type in want_cmd]
            pub = [e for e in seen.values() if e.kind == "MP" and e.topic == self.odom_topic and e.dds_type == want_odom]
            if sub and pub:
                return min(sub, key=lambda e: e.key), min(pub, key=lambda e: e.key)
            return None

        watch = self.bus.watch_alive(ros2.liveliness_any(self.domain), on)
        try:
            with cond:
                got = cond.wait_for(found, timeout=self.discover_timeout_s)
                snapshot = list(seen.values())
        finally:
            watch.close()
        if not got:
            raise DiscoveryError(self._not_found(snapshot, want_cmd, want_odom))
        return got

    def _not_found(self, seen: list[Entity], want_cmd: set[str], want_odom: str) -> str:
        missing = []
        if not any(e.kind == "MS" and e.topic == self.cmd_topic and e.dds_type in want_cmd for e in seen):
            missing.append(f"subscriber of {self.cmd_topic} as " + (
                f"{ros2.TWIST} or {ros2.TWIST_STAMPED}" if len(want_cmd) > 1 else self.cmd_type))
        if not any(e.kind == "MP" and e.topic == self.odom_topic and e.dds_type == want_odom for e in seen):
            missing.append(f"publisher of {self.odom_topic} as {ros2.ODOMETRY}")
        lines = [f"ROS 2 robot {self.namespace or '/'}: found no {' and no '.join(missing)} on domain {self.domain} "
                 f"within {self.discover_timeout_s:g} s (rmw_zenoh liveliness tokens under "
                 f"{ros2.liveliness_any(self.domain)})."]
        for e in seen:
            if e.kind == "MS" and e.topic == self.cmd_topic and e.dds_type not in want_cmd:
                other = "stamped" if e.dds_type == ros2.dds_type(ros2.TWIST_STAMPED) else "plain"
                lines.append(f"The robot subscribes {e.topic} as {e.dds_type}: use --twist {other}.")
        topics = sorted({f"{e.kind} {e.topic} {e.dds_type} (node {e.namespace.rstrip('/')}/{e.node})"
                         for e in seen if e.topic is not None})
        nodes = sorted({f"{e.namespace.rstrip('/')}/{e.node}" for e in seen if e.kind == "NN"})
        if seen:
            lines.append(f"Seen {len(nodes)} node(s): {', '.join(nodes[:12]) or '-'}; topics: "
                         + ("; ".join(topics[:20]) + (f"; and {len(topics) - 20} more" if len(topics) > 20 else "")
                            if topics else "-"))
        else:
            lines.append("No ROS 2 entity at all: is the robot's bringup running with "
                         "RMW_IMPLEMENTATION=rmw_zenoh_cpp, its zenoh router linked to this one, and ROS_DOMAIN_ID "
                         f"{self.domain}? (With zenoh-bridge-ros2dds on the robot, use --ros-flavor bridge.)")
        return " ".join(lines)


def drive_entities(*, domain: int, namespace: str, zid: str, cmd_topic: str, odom_topic: str, cmd_key: str,
                   odom_key: str) -> list[Entity]:
    """The drive as a ROS 2 node would appear: node swarm_drive in the robot's namespace, publishing
    cmd_vel and subscribing odom (what a teleop or Nav2 controller would show)."""
    ns = "/" + namespace if namespace else "/"
    qos = ros2.qos_string(QOS_DEPTH)
    common: dict[str, Any] = dict(domain=domain, zid=zid, nid="0", enclave="/", namespace=ns, node=NODE)
    return [Entity(eid="0", kind="NN", **common),
            Entity(eid="1", kind="MP", topic=cmd_topic, dds_type=cmd_key.split("/")[-2],
                   type_hash=cmd_key.split("/")[-1], qos=qos, **common),
            Entity(eid="2", kind="MS", topic=odom_topic, dds_type=odom_key.split("/")[-2],
                   type_hash=odom_key.split("/")[-1], qos=qos, **common)]

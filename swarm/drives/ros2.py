"""The ROS 2 drive: a swarm agent moves a ROS 2 robot (a TurtleBot3, say) over zenoh (docs/ros2.md).

    drive = Ros2Drive(bus, namespace="robot1", flavor="rmw_zenoh", twist="plain", domain=0,
                      initial_pose=(x0, y0, theta0), now=lambda: agent.sim_time(clock.time()))
    drive.start()          # rmw_zenoh: find the robot's cmd_vel subscriber and odom publisher (DiscoveryError)
    poses = drive.wait()   # swarm.proto.protocol.Pose in the swarm's frame, t = now() at receipt
    drive.send(cmd)        # geometry_msgs Twist or TwistStamped on cmd_vel (reliable: congestion control BLOCK)
    drive.halt("e-stop")   # zero velocity now, latched until the next send()
    drive.close()          # halt, then release

Odometry (nav_msgs/msg/Odometry on <ns>/odom) is the robot's pose in its own odom frame, which starts
wherever the robot was when its odometry started. The drive anchors that frame on the first odometry
message it receives: T_anchor = T_init * T_odom0^-1, so the first pose is the robot's start in the
scenario (initial_pose) and every later one is T_anchor * T_odom. Headings are unwrapped (continuous,
like the simulated world's). Bad odometry is dropped and counted in `bad`.

Flavours: rmw_zenoh (the robot runs rmw_zenoh: the exact data keys, hash included, come from the
robot's liveliness tokens, and every command carries the attachment rmw_zenoh requires; the drive
announces itself as a ROS 2 node, swarm_drive in the robot's namespace, so `ros2 node list` and
`ros2 topic info` show who drives the robot) and bridge (the robot runs zenoh-bridge-ros2dds: keys
<ns>/cmd_vel and <ns>/odom, plain CDR; the cmd_vel type from the route the bridge announces, or its admin space).

Threads: wait(), drain() and close() from the agent's loop thread; send() and halt() from any thread
(a lock keeps the commands and their sequence numbers in order); wake() from any thread.

Finding the robot's topics over rmw_zenoh, and the node the drive announces: swarm.drives.ros2_graph.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from typing import TYPE_CHECKING, Callable, cast

from swarm.core.safety import RAMP_S
from swarm.drives.base import DriveBase
from swarm.drives.ros2_graph import Discovery, DiscoveryError, drive_entities
from swarm.proto import protocol, ros2
from swarm.proto.protocol import Cmd, Pose
from swarm.proto.ros2 import Ros2Error

if TYPE_CHECKING:
    from swarm.net.bus import Closable, Inbox

log = logging.getLogger("swarm.drive.ros2")

DISCOVER_TIMEOUT_S = 10.0
DISTRO_TWIST = {"jazzy": "stamped", "rolling": "stamped", "humble": "plain"}  # a TurtleBot3's cmd_vel type there
BRIDGE_ADMIN_S = 1.0  # s the bridge flavour waits for the bridges' admin space when no route token came
BRIDGE_LOOK_S = 2.0  # s the bridge flavour waits for the route of the robot's cmd_vel (its type) before going on
ODOM_DEPTH = 16  # odometry messages kept between two reads of the agent (the newest)
HALT_REPEATS = 3  # zero commands sent by halt() (reliable already; a few more cost nothing)
FRAME_ID = "base_link"  # TwistStamped's header frame
ODOM_JUMP_M, ODOM_JUMP_RAD = 0.5, 0.5  # odometry back at its origin from this far in one sample has restarted
ODOM_ORIGIN = 1e-3  # m and rad: a restarted odometry's first samples are at (0, 0, 0)
STILL_SAY_S = 2.0  # s of commands that move with odometry that does not: said once (the robot drops them?)
STILL_EPS = (1e-3, 1e-3)  # m, rad: odometry that moved less than this has not moved


def _restarted(prev: tuple[float, float, float], odom: tuple[float, float, float]) -> bool:
    """Odometry back at its origin (0, 0, 0) from ODOM_JUMP_M or ODOM_JUMP_RAD away in one sample: the robot's node
    restarted (a base cannot drive that far in one sample period, and a long gap between samples does not bring it
    back to exactly its origin)."""
    at_origin = abs(odom[0]) < ODOM_ORIGIN and abs(odom[1]) < ODOM_ORIGIN and abs(odom[2]) < ODOM_ORIGIN
    return at_origin and (math.hypot(prev[0], prev[1]) > ODOM_JUMP_M or abs(ros2.wrap(prev[2])) > ODOM_JUMP_RAD)


class Ros2Drive(DriveBase):
    name = "ros2"
    enforces_validity = False  # a base runs its last cmd_vel on: the agent's guard halts it when a command runs out
    ramp_s = RAMP_S  # the base must stop within this of a zero cmd_vel (docs/deploy.md; real time's safety rule)
    switch_s = RAMP_S  # and follow a new one within this

    def __init__(self, bus, *, namespace: str, now: Callable[[], float | None], flavor: str = "rmw_zenoh",
                 twist: str = "plain", domain: int = 0, initial_pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 discover_timeout_s: float = DISCOVER_TIMEOUT_S, odom_depth: int = ODOM_DEPTH,
                 wall_ns: Callable[[], int] = time.time_ns, announce: bool = True,
                 base_timeout_s: float | None = None, attachment: str = "auto",
                 monotonic: Callable[[], float] = time.monotonic, bridge_look_s: float = BRIDGE_LOOK_S,
                 speed_limits: tuple[float, float] | None = None, distro: str | None = None) -> None:
        """now(): the swarm's clock [s] (None until it is known: poses are not reported before);
        wall_ns(): the wall clock [ns since the epoch] for TwistStamped headers and attachments;
        base_timeout_s: how long the robot's base executes a cmd_vel with no newer one (the inventory's
        cmd_timeout; None: not known): should the agent die, its last command acts that long, and real time's
        safety rule counts it in the robot's reach; twist: the cmd_vel type, plain (Twist), stamped (TwistStamped)
        or "auto": the type the robot subscribes (rmw_zenoh: its token; bridge: the bridge's route; plain when a
        bridge announces none, or distro's TurtleBot3 default); speed_limits: the robot's own (v_max [m/s], w_max [rad/s]), say its model's
        (--robot-model): the agent tightens its run's limits to them; attachment: the form of rmw_zenoh's attachment the commands
        carry (ros2.ATTACHMENT_FORMS: v1 for the releases before the 33-byte form, v2 after), or "auto": the form of
        the robot's own odometry (v2 until its first sample says)."""
        self.bus, self.now, self.wall_ns, self.monotonic = bus, now, wall_ns, monotonic
        if attachment != "auto":
            ros2.check_attachment_form(attachment)
        self.attachment_given = attachment
        self.attachment: str = "v2" if attachment == "auto" else attachment  # the form commands carry
        self.robot_attachment: str | None = None  # the form the robot's odometry carries, once seen
        self.namespace = ros2.check_namespace(namespace)
        self.flavor = ros2.check_flavor(flavor)
        if twist != "auto":
            ros2.twist_type(twist)
        if distro not in (None, *DISTRO_TWIST):
            raise ValueError(f"distro must be one of {', '.join(DISTRO_TWIST)}, got {distro!r}")
        self.twist_given = twist
        # auto: start() finds the robot's; until then (and behind a bridge that says nothing) its distro's default
        self.twist = DISTRO_TWIST.get(distro or "", "plain") if twist == "auto" else twist
        self.cmd_type = ros2.twist_type(self.twist)
        self.domain = ros2.check_domain(domain)
        if len(initial_pose) != 3 or not all(isinstance(a, (int, float)) and math.isfinite(a) for a in initial_pose):
            raise ValueError(f"initial_pose must be three finite numbers (x, y, theta), got {initial_pose!r}")
        self.initial_pose = cast("tuple[float, float, float]", tuple(float(a) for a in initial_pose))
        if not discover_timeout_s > 0:
            raise ValueError(f"discover_timeout_s must be > 0, got {discover_timeout_s}")
        self.discover_timeout_s = discover_timeout_s
        self.bridge_look_s = bridge_look_s
        if speed_limits is not None and not (len(speed_limits) == 2 and all(
                isinstance(a, (int, float)) and math.isfinite(a) and a > 0 for a in speed_limits)):
            raise ValueError(f"speed_limits must be two finite numbers > 0 (v_max, w_max), got {speed_limits!r}")
        self.speed_limits = speed_limits  # the robot's own (v_max, w_max), e.g. its model's: the agent keeps to them
        self.odom_depth = odom_depth
        self.announce = announce
        self.base_timeout_s: float | None = base_timeout_s
        self.cmd_topic = ros2.topic_name(self.namespace, ros2.CMD_VEL)
        self.odom_topic = ros2.topic_name(self.namespace, ros2.ODOM)
        ros2.require()  # fail now, naming the extra, if rosbags or xxhash is missing
        self.zid = os.urandom(16).hex()  # the zenoh id of the node the drive announces
        self.gid = os.urandom(ros2.GID_SIZE)  # its cmd_vel publisher's gid in every attachment (start(): rmw_zenoh's)
        self.cmd_key: str | None = None
        self.odom_key: str | None = None
        self.bad = protocol.BadMessages(log)
        self.seq = 0  # poses reported
        self.sent = 0  # commands sent (halts included)
        self.unclocked = 0  # odometry received while now() was None (anchors, but no pose reported)
        self.untold = 0  # odometry received before its attachment said the robot's release (auto: no pose reported)
        self.resets = 0  # odometry frames re-anchored after a jump (the robot's node restarted)
        self.halted: str | None = "not started"  # the reason of the latched halt; None while commanded
        self._anchor: tuple[float, float, float] | None = None
        self._theta: float = self.initial_pose[2]
        self._att_seq = 0
        self._moving_since: float | None = None  # monotonic: commands that move went out from then, odometry still
        self._odom_at_move: tuple[float, float, float] | None = None
        self._odom_last: tuple[float, float, float] | None = None
        self.still_said = False  # the "commands but no motion" warning was given
        self._late_said = False  # a bridge route that came late and contradicts --twist was said
        self._send_lock = threading.Lock()
        self._pose_lock = threading.Lock()
        self._box: Inbox | None = None  # start() sets it
        self._handles: list[Closable] = []
        self._closed = False

    def __repr__(self) -> str:
        return f"Ros2Drive({self.flavor}, {self.cmd_topic} as {self.cmd_type}, domain {self.domain})"

    # ------------------------------------------------------------------ wiring

    def start(self, on_poses: Callable[[list[Pose]], None] | None = None) -> None:
        """Find the keys (rmw_zenoh: from the robot's liveliness tokens, DiscoveryError after
        discover_timeout_s), subscribe to odometry, announce the drive's node (rmw_zenoh). Poses wait in an inbox
        (takes_callback is False: on_poses must be None)."""
        if on_poses is not None:
            raise ValueError("Ros2Drive hands its poses over through wait() and drain(), not a callback")
        if self.flavor == "bridge":
            self.cmd_key = ros2.bridge_key(self.namespace, ros2.CMD_VEL)
            self.odom_key = ros2.bridge_key(self.namespace, ros2.ODOM)
            self._check_bridge_route()
        else:
            sub, pub = Discovery(self.bus, namespace=self.namespace, domain=self.domain, cmd_topic=self.cmd_topic,
                                 odom_topic=self.odom_topic, cmd_type=self.cmd_type, twist_given=self.twist_given,
                                 discover_timeout_s=self.discover_timeout_s).find()
            self.cmd_key, self.odom_key = sub.data_key, pub.data_key
            if self.twist_given == "auto":
                self._take_twist(cast(str, sub.dds_type), "its rmw_zenoh token")
            for e, what in ((sub, self.cmd_type), (pub, ros2.ODOMETRY)):
                if e.type_hash not in (ros2.type_hash(what), ros2.NO_HASH):
                    log.warning("%s: %s on %s has type hash %s, not Jazzy's %s: its message definition differs "
                                "and the bytes may not match", self.namespace, e.node, e.topic, e.type_hash,
                                ros2.type_hash(what))
        self._box = self.bus.inbox(self.odom_key, depth=self.odom_depth)
        self._handles.append(self._box)
        if self.flavor == "rmw_zenoh":  # the attachment of the robot's own samples says its release
            self._handles.append(self.bus.subscribe_raw(self.odom_key, self._on_odom_attachment))
        if self.flavor == "rmw_zenoh":
            entities = drive_entities(domain=self.domain, namespace=self.namespace, zid=self.zid,
                                      cmd_topic=self.cmd_topic, odom_topic=self.odom_topic,
                                      cmd_key=self.cmd_key, odom_key=self.odom_key)
            self.gid = ros2.entity_gid(entities[1].key)  # the cmd_vel publisher's, as rmw_zenoh derives it
            for e in entities if self.announce else ():
                self._handles.append(self.bus.token(e.key))
        log.info("%r: commands on %s, odometry from %s", self, self.cmd_key, self.odom_key)

    def _take_twist(self, typename: str, said_by: str) -> None:
        """twist auto: command the robot in the cmd_vel type it subscribes (`typename`, as `said_by` tells)."""
        self.twist = cast(str, ros2.twist_of(typename))
        self.cmd_type = ros2.twist_type(self.twist)
        log.info("%s subscribes %s as %s (%s): commands go out so", self.namespace or "/", self.cmd_topic,
                 self.cmd_type, said_by)

    def _check_bridge_route(self) -> None:
        """Bridge flavour: the route zenoh-bridge-ros2dds announces for the robot's cmd_vel says the type it
        subscribes (twist auto takes it; a --twist of the other type is refused with the fix: the bridge would
        pass the bytes on and the robot would read nonsense or nothing); a route only on the doubled key means the
        namespace was given twice (DiscoveryError naming it). With no token within bridge_look_s, the bridges'
        admin space answers instead (`@/<zid>/ros2/route/topic/sub/<key>`, its `ros2_type`). A bridge that says
        neither (the robot's nodes not up yet) is said, the commands go out as given (auto: the distro's default, or
        plain), and the drive keeps listening: a route that comes later sets the type (auto) or is said (given)."""
        doubled = ros2.doubled_bridge_key(self.namespace, ros2.CMD_VEL)
        routes: dict[str, dict[str, ros2.BridgeRoute]] = {}  # key -> token -> route, alive ones only
        cond = threading.Condition()
        late: list[bool] = []  # set once start() has gone on without a type: a route from then on is applied

        def on(key: str, alive: bool) -> None:
            r = ros2.parse_bridge_route(key)
            if r is None or r.key not in (self.cmd_key, doubled):
                return
            with cond:
                if alive:
                    routes.setdefault(r.key, {})[key] = r
                else:
                    routes.get(r.key, {}).pop(key, None)
                cond.notify_all()
                now = late and alive and r.key == self.cmd_key
            if now:
                self._late_route(r.ros2_type)

        watches = [self.bus.watch_alive(expr, on) for expr in ros2.bridge_routes("MS")]
        with cond:
            cond.wait_for(lambda: bool(routes.get(cast(str, self.cmd_key))), timeout=self.bridge_look_s)
            mine = min(routes.get(cast(str, self.cmd_key), {}).values(), key=lambda r: r.zid, default=None)
            twice = bool(routes.get(doubled or "")) if doubled else False
        typ = mine.ros2_type if mine is not None else None
        if typ is None and not twice:
            typ = self._bridge_admin_type()
        if typ is None and not twice:
            with cond:
                late.append(True)
            self._handles.extend(watches)  # a route that comes later still tells the type (_late_route)
            log.warning("%s: no zenoh-bridge-ros2dds announces a route for %s within %g s, nor has one in its admin "
                        "space (the robot's nodes are not up yet, or its bridge says nothing): commands go out as %s "
                        "until one does; a Jazzy TurtleBot3 takes TwistStamped (--twist stamped), a Humble one Twist "
                        "(--twist plain)", self.namespace or "/", self.cmd_key, self.bridge_look_s, self.cmd_type)
            return
        for w in watches:
            w.close()
        if typ is None:
            raise DiscoveryError(
                f"ROS 2 robot {self.namespace}: nothing subscribes {self.cmd_key}, but the bridge routes {doubled} to "
                f"a subscriber: the namespace is given twice (the robot's nodes in /{self.namespace} and its "
                f"zenoh-bridge-ros2dds started with -n /{self.namespace}); start the bridge without -n, or the "
                "robot's nodes without their namespace")
        said_by = "the bridge's route" if mine is not None else "the bridge's admin space"
        twist = ros2.twist_of(typ)
        if twist is None:
            raise DiscoveryError(f"ROS 2 robot {self.namespace}: the bridge routes {self.cmd_key} to a subscriber of "
                                 f"{typ}, neither {ros2.TWIST} nor {ros2.TWIST_STAMPED}")
        if self.twist_given == "auto":
            self._take_twist(typ, said_by)
        elif twist != self.twist:
            raise DiscoveryError(f"ROS 2 robot {self.namespace}: the robot subscribes {self.cmd_topic} as "
                                 f"{typ} (its zenoh-bridge-ros2dds says so), not as {self.cmd_type}: use "
                                 f"--twist {twist} (or auto)")

    def _late_route(self, typ: str) -> None:
        """A route of the robot's cmd_vel that came after start() went on without one (on the bus's thread): auto
        takes its type from the next command on; a given --twist of the other type is said (the robot takes none of
        its commands)."""
        twist = ros2.twist_of(typ)
        if twist is None or twist == self.twist:
            return
        if self.twist_given == "auto":
            with self._send_lock:
                self._take_twist(typ, "the bridge's route, come late")
        elif not self._late_said:
            self._late_said = True
            log.error("%s: the robot subscribes %s as %s (its zenoh-bridge-ros2dds says so now), not as %s: it takes "
                      "none of these commands; give --twist %s (or auto)", self.namespace or "/", self.cmd_topic, typ,
                      self.cmd_type, twist)

    def _bridge_admin_type(self) -> str | None:
        """The cmd_vel route's ROS 2 type from the bridges' admin space (`@/<zid>/ros2/route/topic/sub/<key>`), for a
        bridge whose route token did not come; None when no bridge answers with one."""
        try:
            replies = self.bus.query(f"{ros2.BRIDGE_ADMIN_SUB}/{self.cmd_key}", timeout_s=BRIDGE_ADMIN_S)
        except Exception as e:  # a router that refuses the admin space's key: said, not fatal
            log.info("%s: the bridges' admin space did not answer (%s)", self.namespace or "/", e)
            return None
        types = sorted({t for t in (ros2.bridge_admin_type(p) for _k, p in replies) if t is not None})
        return types[0] if types else None

    def _on_odom_attachment(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        """The first odometry sample's attachment form: auto takes it for the commands; a given form that differs
        is said once (that robot's rmw_zenoh drops every command)."""
        if self.robot_attachment is not None:
            return
        form = ros2.attachment_form(attachment)
        if form is None:
            log.warning("%s: odometry on %s carries %s, neither rmw_zenoh attachment form: commands go out as %s",
                        self.namespace, key, "no attachment" if attachment is None else f"{len(attachment)} bytes",
                        self.attachment)
            self.robot_attachment = "unknown"
            return
        self.robot_attachment = form
        if self.attachment_given == "auto":
            self.attachment = form
            log.info("%s: the robot's attachments are %s (%s): commands carry the same", self.namespace, form,
                     ros2.RELEASES[form])
        elif form != self.attachment:
            log.error("%s: the robot's odometry carries %s attachments (%s) and --rmw-zenoh-attachment is %s: its "
                      "rmw_zenoh drops every command. Give --rmw-zenoh-attachment %s, or auto", self.namespace, form,
                      ros2.RELEASES[form], self.attachment, form)

    def close(self) -> None:
        """Halt, then release the subscription and the tokens (from the loop thread, after wait() returned)."""
        if self._closed:
            return
        self._closed = True
        if self.cmd_key is not None:
            self.halt("drive closed")
        for h in reversed(self._handles):
            h.close()
        self._handles.clear()

    # ------------------------------------------------------------------ poses

    def wait(self) -> list[Pose]:
        """Block until odometry comes (or wake()); the poses of all that came (maybe []: a wake, or
        odometry that was bad or came before the clock)."""
        box = cast("Inbox", self._box)
        items = box.wait()  # zenoh's inbox hands the first sample here and keeps the rest for drain()
        return self._poses(items + box.drain())

    def drain(self) -> list[Pose]:
        return self._poses(cast("Inbox", self._box).drain())

    def wake(self) -> None:
        cast("Inbox", self._box).wake()

    def _poses(self, items: list[tuple[str, bytes]]) -> list[Pose]:
        out = []
        with self._pose_lock:
            for key, payload in items:
                try:
                    o = ros2.decode_odometry(payload)
                except Ros2Error as e:
                    self.bad.reject(key, e)
                    continue
                if self.robot_attachment is None and self.attachment_given == "auto" and self.flavor == "rmw_zenoh":
                    self.untold += 1  # its form not known yet (the raw subscription's callback is on its way): no
                    continue  # pose, so no command goes out in a form the robot may drop
                odom = (o.x, o.y, o.yaw)
                prev = self._odom_last
                self._watch_motion(odom)
                if self._anchor is None:  # the odom frame's origin in the swarm's frame
                    self._anchor = ros2.se2_compose(self.initial_pose, ros2.se2_inverse(odom))
                elif prev is not None and _restarted(prev, odom):
                    self._reanchor(prev, odom)
                t = self.now()
                if t is None:
                    self.unclocked += 1
                    continue
                x, y, th = ros2.se2_compose(self._anchor, odom)
                self._theta += ros2.wrap(th - self._theta)
                out.append(Pose(t=t, seq=self.seq, x=x, y=y, theta=self._theta))
                self.seq += 1
        return out

    def _reanchor(self, prev: tuple[float, float, float], odom: tuple[float, float, float]) -> None:
        """The robot's odometry jumped between two samples (its node restarted and its odom frame with it): anchor the
        new frame so that the robot is where the last sample put it, and say so."""
        assert self._anchor is not None
        where = ros2.se2_compose(self._anchor, prev)  # the robot in the swarm's frame, before the jump
        self._anchor = ros2.se2_compose(where, ros2.se2_inverse(odom))
        self.resets += 1
        log.warning("%s: odometry on %s jumped from (%.3f, %.3f, %.3f) to (%.3f, %.3f, %.3f) between two samples (its "
                    "node restarted?): re-anchored, the robot stays at (%.3f, %.3f) in the swarm's frame",
                    self.namespace, self.odom_key, *prev, *odom, where[0], where[1])

    def _watch_motion(self, odom: tuple[float, float, float]) -> None:
        """Say once when commands that move have gone out for STILL_SAY_S and the odometry has not moved: the
        robot takes no command (the attachment form, the twist type, a namespace), or something holds it."""
        self._odom_last = odom
        if self._moving_since is None:
            return
        if self._odom_at_move is None:
            self._odom_at_move = odom
        ref = self._odom_at_move
        moved = abs(odom[0] - ref[0]) + abs(odom[1] - ref[1]) > STILL_EPS[0]
        if moved or abs(ros2.wrap(odom[2] - ref[2])) > STILL_EPS[1]:
            self._moving_since, self._odom_at_move = None, None  # it moves: commands arrive
            return
        if not self.still_said and self.monotonic() - self._moving_since >= STILL_SAY_S:
            self.still_said = True
            log.warning("%s: commands that move have gone out on %s for %.0f s and the odometry did not move: the "
                        "robot takes none of them (%s; its twist type, here %s; its namespace), or something holds it",
                        self.namespace, self.cmd_key, STILL_SAY_S,
                        f"the attachment form, here {self.attachment}" if self.flavor == "rmw_zenoh" else
                        "the bridge's namespace", self.cmd_type)

    # ------------------------------------------------------------------ commands

    def send(self, cmd: Cmd) -> None:
        """cmd.v [m/s], cmd.w [rad/s] on cmd_vel; clears a halt. A non-finite command halts the robot
        and raises ValueError (the law never gives one: something upstream is broken)."""
        if not (math.isfinite(cmd.v) and math.isfinite(cmd.w)):
            self.halt(f"non-finite command v = {cmd.v}, w = {cmd.w}")
            raise ValueError(f"non-finite command v = {cmd.v}, w = {cmd.w}: robot halted")
        with self._send_lock:
            self._put(cmd.v, cmd.w)
            self.halted = None

    def halt(self, reason: str) -> None:
        """Zero velocity now (HALT_REPEATS times), latched until the next send()."""
        with self._send_lock:
            if self.cmd_key is not None:
                for _ in range(HALT_REPEATS):
                    self._put(0.0, 0.0)
            if self.halted != reason:
                log.info("%s halted: %s", self.cmd_topic, reason)
            self.halted = reason

    def _put(self, v: float, w: float) -> None:
        if self.cmd_key is None:
            raise RuntimeError("Ros2Drive.send() before start()")
        now_ns = self.wall_ns()
        if v == 0.0 and w == 0.0:
            self._moving_since, self._odom_at_move = None, None
        elif self._moving_since is None:
            self._moving_since, self._odom_at_move = self.monotonic(), self._odom_last
        if self.cmd_type == ros2.TWIST:
            payload = ros2.encode_twist(v, w)
        else:
            payload = ros2.encode_twist_stamped(v, w, now_ns, FRAME_ID)
        if self.flavor == "rmw_zenoh":
            self._att_seq += 1
            att = ros2.encode_attachment(self._att_seq, now_ns, self.gid, self.attachment)
            self.bus.put(self.cmd_key, payload, reliable=True, attachment=att)
        else:
            self.bus.put(self.cmd_key, payload, reliable=True)
        self.sent += 1

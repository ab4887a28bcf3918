"""The simulated robot's drive: the world's keys (`robot/<id>/pose` in, `robot/<id>/cmd` out).

This is the default of `swarm robot` and what `swarm up` runs in real time: the world integrates the
command and publishes the pose. A command carries the time of the pose it answers (the world measures
the round trip with it) and this drive's own counter (halts included: the world's window on a
robot's commands only moves forward).
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, cast

from swarm.core.safety import RAMP_S
from swarm.drives.base import DriveBase
from swarm.proto import keys, protocol
from swarm.proto.protocol import Cmd, Limits, Pose, ProtocolError

if TYPE_CHECKING:
    from swarm.net.bus import Inbox

log = logging.getLogger("swarm.drive")

POSE_DEPTH = 8  # poses kept until the agent takes them (the newest: older ones are of no use)


class SimDrive(DriveBase):
    name = "sim"
    periodic = True  # the world puts each robot's pose once a control period: a pose that does not come was lost
    enforces_validity = True  # the world executes a command only until its `until`, then brakes (docs/runtime.md)
    ramp_s = RAMP_S  # along this ramp
    switch_s = 0.0  # and takes a new command at once
    takes_callback = True  # start(on_poses): poses handed to a callback on the bus's thread instead of an inbox

    def __init__(self, bus, fleet: str, robot_id: int, limits: Limits | None = None) -> None:
        self.bus, self.fleet, self.id = bus, fleet, robot_id
        self.limits = limits
        self.pose_key = keys.robot_pose(fleet, robot_id)
        self.cmd_key = keys.robot_cmd(fleet, robot_id)
        self.bad = protocol.BadMessages(log)
        self.halted: str | None = "not started"
        self.sent = 0
        self._lock = threading.Lock()
        self._t = 0.0  # the time of the last command's pose
        self._box: Inbox | None = None  # start() sets it
        self._enc = protocol.encoder("cmd")

    def start(self, on_poses=None) -> None:
        """Subscribe to this robot's poses: into an inbox that wait() and drain() take from, or, with
        on_poses, to a callback on the bus's thread that hands on_poses each pose decoded (a bad one counted;
        wait() and drain() then have nothing to give)."""
        if on_poses is None:
            self._box = self.bus.inbox(self.pose_key, depth=POSE_DEPTH)
            return
        dec = protocol.decoder("pose", self.limits)

        def on_pose(key: str, data: bytes) -> None:
            try:
                pose = dec(data)
            except ProtocolError as e:
                self.bad.reject(key, e)
                return
            on_poses((pose,))

        self._box = _Subscribed(self.bus.subscribe(self.pose_key, on_pose))

    def wait(self) -> list[Pose]:
        """Block until a pose came (or wake()): the poses that came, decoded (bad ones counted)."""
        return self._poses(cast("Inbox", self._box).wait())  # a pose that comes later: the agent's drain() takes it

    def drain(self) -> list[Pose]:
        return self._poses(cast("Inbox", self._box).drain())

    def wake(self) -> None:
        cast("Inbox", self._box).wake()

    def _poses(self, items: list[tuple[str, bytes]]) -> list[Pose]:
        out = []
        dec = protocol.decoder("pose", self.limits)  # made once per limits (protocol.decode's own)
        for key, data in items:
            try:
                out.append(dec(data))
            except ProtocolError as e:
                self.bad.reject(key, e)
        return out

    def _put(self, t: float, v: float, w: float, until: float | None) -> None:
        self.bus.put(self.cmd_key, self._enc(t, self.sent, v, w, until), reliable=True)  # a Cmd's fields, in order
        self.sent += 1
        self._t = t

    def send(self, cmd: Cmd) -> None:
        with self._lock:
            self._put(cmd.t, cmd.v, cmd.w, cmd.until)
            self.halted = None

    def halt(self, reason: str) -> None:
        """Zero velocity now, latched until send()."""
        with self._lock:
            self._put(self._t, 0.0, 0.0, None)
            if self.halted != reason:
                log.info("robot %d halted: %s", self.id, reason)
            self.halted = reason

    def hold(self, t: float) -> None:
        """Halted: zero velocity at time t (each period while halted, so the world's window on this robot's commands
        moves on, and the first command after the halt is not a jump)."""
        with self._lock:
            if self.halted is not None:
                self._put(t, 0.0, 0.0, None)

    def close(self) -> None:
        if self._box is None:
            return
        try:
            self.halt("closing")
        except Exception as e:  # the session is already gone: nothing more to tell the world
            log.debug("robot %d: no last halt: %s", self.id, e)
        self._box.close()
        self._box = None


class _Subscribed:
    """SimDrive's poses through a callback: an inbox with nothing in it (the callback has them)."""

    def __init__(self, handle) -> None:
        self.handle = handle
        self._woken = threading.Event()

    def wait(self) -> list:
        self._woken.wait()
        self._woken.clear()
        return []

    def drain(self) -> list:
        return []

    def wake(self) -> None:
        self._woken.set()

    def close(self) -> None:
        self.handle.close()

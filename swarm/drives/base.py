"""The drive interface: how a robot agent gets its pose and moves its body, whatever the body is.

    drive.start()                 subscribe / discover what it needs; poses may arrive after it
    poses = drive.wait()          block until a new pose came (or wake()): [Pose, ...], [] on wake
    poses = drive.drain()         the poses that came since, without blocking
    drive.wake()                  from another thread: a blocked wait() returns
    drive.send(cmd)               command the body: cmd.v [m/s], cmd.w [rad/s]; cmd.t = the time of the
                                  pose it answers, cmd.seq the agent's counter
    drive.halt(reason)            zero velocity now (watchdog, e-stop, shutdown, an exception); the body
                                  stays halted until the next send()
    drive.close()                 halt, then release everything
    drive.speed_limits            the body's own (v_max [m/s], w_max [rad/s]), e.g. its model's, or None: the
                                  agent tightens its run's limits to them before its first command

Poses are swarm.proto.protocol.Pose in the swarm's frame (the scenario's metres and radians) and on
the swarm's simulated clock (t [s]); seq counts the poses of this drive. A drive never raises on a
bad incoming message: it drops it and counts it in `drive.bad` (a swarm.proto.protocol.BadMessages).
Everything a drive does on the network goes through the bus it is given (swarm.net.bus), so fault
injection and security wrap it like any other process.
"""

from __future__ import annotations

from typing import Protocol

from swarm.proto.protocol import Cmd, Pose


class Drive(Protocol):
    name: str  # "sim", "ros2"
    speed_limits: tuple[float, float] | None  # the body's own (v_max, w_max), or None

    def start(self) -> None: ...

    def wait(self) -> list[Pose]: ...

    def drain(self) -> list[Pose]: ...

    def wake(self) -> None: ...

    def send(self, cmd: Cmd) -> None: ...

    def halt(self, reason: str) -> None: ...

    def close(self) -> None: ...

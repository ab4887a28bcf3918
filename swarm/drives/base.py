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
    drive.hold(t)                 the guard halted the body at this period's time t (the simulated drive puts a
                                  zero command of time t: the world's window on its commands moves on)
    drive.speed_limits            the body's own (v_max [m/s], w_max [rad/s]), e.g. its model's, or None: the
                                  agent tightens its run's limits to them before its first command

Poses are swarm.proto.protocol.Pose in the swarm's frame (the scenario's metres and radians) and on
the swarm's simulated clock (t [s]); seq counts the poses of this drive. A drive never raises on a
bad incoming message: it drops it and counts it in `drive.bad` (a swarm.proto.protocol.BadMessages).
Everything a drive does on the network goes through the bus it is given (swarm.net.bus), so fault
injection and security wrap it like any other process. A drive is a DriveBase (the defaults of every
attribute the agent reads) and meets the Drive protocol: the agent reads no attribute it does not declare.
"""

from __future__ import annotations

from typing import Callable, Protocol

from swarm.core.safety import RAMP_S
from swarm.proto.protocol import Cmd, Limits, Pose


class Drive(Protocol):
    """What the agent calls, as declared (DriveBase gives every attribute its default)."""

    name: str  # "sim", "ros2"
    pose_key: str  # where a bad pose is said to come from
    periodic: bool  # poses come once a control period: one that does not come was lost
    takes_callback: bool  # start(on_poses) hands poses to a callback on the bus's thread instead of an inbox
    enforces_validity: bool  # the body executes a command only until its `until`, then brakes
    ramp_s: float  # along this ramp [s]
    switch_s: float  # and takes a new command within this [s]
    base_timeout_s: float | None  # how long the body acts on a command with no newer one (None: unknown)
    speed_limits: tuple[float, float] | None  # the body's own (v_max, w_max), or None
    limits: Limits | None  # the scenario's bounds the poses are decoded with (None: the agent gives them)
    halted: str | None  # why the body stands, latched from halt() until the next send(); None while commanded

    def start(self, on_poses: Callable[[list[Pose]], None] | None = None) -> None: ...

    def wait(self) -> list[Pose]: ...

    def drain(self) -> list[Pose]: ...

    def wake(self) -> None: ...

    def send(self, cmd: Cmd) -> None: ...

    def hold(self, t: float) -> None: ...

    def halt(self, reason: str) -> None: ...

    def close(self) -> None: ...


class DriveBase:
    """The defaults of a drive's attributes: a body whose poses come when they come, that runs its last command
    on (the agent's guard halts it when the command runs out), braking within RAMP_S; hold() does nothing (the
    guard has halted it already)."""

    name = "drive"
    pose_key = "pose"
    periodic = False
    takes_callback = False
    enforces_validity = False
    ramp_s = RAMP_S
    switch_s = RAMP_S
    base_timeout_s: float | None = None
    speed_limits: tuple[float, float] | None = None
    limits: Limits | None = None
    halted: str | None = "not started"

    def hold(self, t: float) -> None:
        """The guard halted the robot at the time t of this control period (a drive that keeps a window on its
        commands, as the world does, moves it on)."""

"""The robot-side watchdog: the reasons a robot must stand still now, checked on the robot itself.

    guard = Guard(drive, clock, pose_timeout_s=0.5, ref_timeout_s=2.5, arena=arena_of(cfg))
    guard.start(now, rate)        # a thread: halts the drive when poses stop coming (the loop is blocked then),
                                  # checking at events and when a timeout may run out (next_check)
    guard.pose(x, y)              # the agent took a pose (x, y [m]: the arena check's)
    reason = guard.reason(t)      # the control loop asks before every command; None: go on
    guard.estop(engaged, why)     # the emergency stop (latched until released)
    guard.leader(alive), guard.world(alive)   # their liveliness tokens came or went

A drive is halted (zero velocity, latched until the next command) when:
- its pose is older than pose_timeout_s (wall clock: odometry or the world stopped);
- its newest pose is outside the arena (the configuration's arena.bounds, `arena_of(cfg)`): it stays
  halted while it is outside, so a robot that left the arena stands where it stopped until a person
  moves it back (a command that would bring it back cannot be told from one that takes it farther);
- the reference has been extrapolated for longer than ref_timeout_s (simulated time since the last
  reference: the leader went quiet);
- the leader's liveliness token is gone (at once: the leader was lost or cut off);
- the world's liveliness token is gone (at once: the world, which puts the poses and referees the run,
  was lost or this robot was cut off from it);
- the emergency stop is engaged (until released);
- its newest command has expired (real time: the swarm's time passed the command's `until`), for a drive that does
  not enforce a command's validity itself (a ROS 2 robot; the simulated world does): the robot's base then
  brakes along its own ramp (docs/runtime.md, "The safety invariant").
Ctrl-C, SIGTERM and any exception end the control loop, whose way out closes the drive, which halts
it. No process can catch its own SIGKILL or SIGSTOP: the robot's base must stop by itself then
(docs/deploy.md says how, per base).
"""

from __future__ import annotations

import logging
import threading

from swarm.core.clock import WALL
from swarm.process import name_thread
from swarm.drives.base import Drive

log = logging.getLogger("swarm.guard")

POSE_TIMEOUT_S = 0.5
REF_TIMEOUT_S = 2.5
MAX_IDLE_S = 1.0  # the longest the guard's thread sleeps without an event (a timeout is known to be farther)


def arena_of(cfg) -> tuple[float, float, float, float] | None:
    """The arena (xmin, xmax, ymin, ymax) [m] of a swarm.proto.protocol.Config, None if it has none."""
    return (cfg.xmin, cfg.xmax, cfg.ymin, cfg.ymax) if cfg.arena else None


class Guard:
    def __init__(self, drive: Drive, clock=WALL, pose_timeout_s: float = POSE_TIMEOUT_S,
                 ref_timeout_s: float = REF_TIMEOUT_S, period_s: float = 0.05,
                 arena: tuple[float, float, float, float] | None = None, expire: bool = False) -> None:
        """arena: (xmin, xmax, ymin, ymax) [m]; None: no arena check. expire: halt the drive when its newest
        command's validity ran out (a drive that does not enforce it itself)."""
        if arena is not None:
            xmin, xmax, ymin, ymax = map(float, arena)
            if not (xmin < xmax and ymin < ymax):
                raise ValueError(f"arena must have xmin < xmax and ymin < ymax, got {tuple(arena)}")
            arena = (xmin, xmax, ymin, ymax)
        self.drive, self.clock, self.arena = drive, clock, arena
        self.pose_timeout_s, self.ref_timeout_s, self.period_s = pose_timeout_s, ref_timeout_s, period_s
        self.last_pose: float | None = None  # monotonic wall time a pose was last taken
        self.xy: tuple[float, float] | None = None  # the newest pose's position [m]
        self.left_at: tuple[float, float] | None = None  # where it was first seen outside the arena (until back in)
        self.ref_t: float | None = None  # simulated time of the newest reference
        self.leader_seen = False
        self.leader_alive = False
        self.world_seen = False
        self.world_alive = False
        self.stopped: str | None = None  # the emergency stop's reason while engaged
        self.expire = expire
        self.until: float | None = None  # simulated time until which the newest command may be executed
        self.halts = 0  # times the guard itself halted the drive
        self._stop = threading.Event()
        self._wake = threading.Event()  # set by stop and by every event that may be a reason: the thread checks now
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ what the agent tells it

    def pose(self, x: float | None = None, y: float | None = None) -> None:
        """A pose was taken now; x, y [m] its position (for the arena check; omitted: not checked)."""
        self.last_pose = self.clock.monotonic()
        if x is not None and y is not None:
            self.xy = (float(x), float(y))
            if self.arena is not None:
                xmin, xmax, ymin, ymax = self.arena
                inside = xmin <= self.xy[0] <= xmax and ymin <= self.xy[1] <= ymax  # NaN is outside
                if not inside and self.left_at is None:
                    self._wake.set()  # a new reason: the thread checks now
                self.left_at = None if inside else (self.left_at or self.xy)

    def ref(self, t: float) -> None:
        self.ref_t = t if self.ref_t is None else max(self.ref_t, t)

    def leader(self, alive: bool) -> None:
        self.leader_alive = alive
        self.leader_seen = self.leader_seen or alive
        self._wake.set()

    def world(self, alive: bool) -> None:
        self.world_alive = alive
        self.world_seen = self.world_seen or alive
        self._wake.set()

    def estop(self, engaged: bool, why: str) -> None:
        if engaged and self.stopped is None:
            log.warning("emergency stop: %s", why or "(no reason given)")
        elif not engaged and self.stopped is not None:
            log.warning("emergency stop released%s", f": {why}" if why else "")
        self.stopped = (why or "engaged") if engaged else None
        self._wake.set()

    # ------------------------------------------------------------------ the verdict

    def reason(self, t: float | None) -> str | None:
        """Why the robot must stand still now (None: it may move); t: the swarm's simulated time."""
        if self.stopped is not None:
            return f"emergency stop ({self.stopped})"
        if self.leader_seen and not self.leader_alive:
            return "the leader is lost"
        if self.world_seen and not self.world_alive:
            return "the world is lost"
        if self.last_pose is not None and self.clock.monotonic() - self.last_pose > self.pose_timeout_s:
            return f"no pose for more than {self.pose_timeout_s:g} s"
        # one reason for the whole time outside: the halt is latched once (left_at is set with an arena only)
        if self.left_at is not None and self.arena is not None:
            (x, y), (xmin, xmax, ymin, ymax) = self.left_at, self.arena
            return f"outside the arena: at ({x:.3f}, {y:.3f}), beyond [{xmin:g}, {xmax:g}] x [{ymin:g}, {ymax:g}]"
        if t is not None and self.ref_t is not None and t - self.ref_t > self.ref_timeout_s:
            return f"the reference has been extrapolated for more than {self.ref_timeout_s:g} s"
        if self.expire and t is not None and self.until is not None and t > self.until:
            return "its newest command expired (no newer one in time)"
        return None

    def check(self, t: float | None, until: float | None = None) -> str | None:
        """Halt the drive if there is a reason (once per reason: the halt is latched). until: the validity of the
        command about to be sent (it is the newest from now on)."""
        if until is not None:
            self.until = until
        why = self.reason(t)
        if why is not None and self.drive.halted != why:
            self.drive.halt(why)
            self.halts += 1
        return why

    # ------------------------------------------------------------------ the thread

    def start(self, now=lambda: None, rate=lambda: 1.0) -> None:
        """Check on a thread of its own (the control loop blocks while no pose comes): at once when an event
        may be a reason (the emergency stop, a token, leaving the arena), and when a timeout may have run out
        (next_check): not every period_s while poses and references keep coming, as the control loop checks
        before every command anyway. now(): the swarm's simulated time, or None while unknown; rate(): simulated
        seconds a wall second (the swarm's speed)."""

        def run() -> None:
            name_thread("guard")
            while not self._stop.is_set():
                self._wake.clear()  # before the check: an event during it ends the wait below at once
                wait = self.period_s
                try:
                    t = now()
                    if self.check(t) is None:
                        wait = self.next_check(t, rate())
                except Exception as e:  # the bus is closing: the loop's way out halts the drive anyway
                    log.debug("guard: %s", e)
                self._wake.wait(wait)

        self._thread = threading.Thread(target=run, name="guard", daemon=True)
        self._thread.start()

    def next_check(self, t: float | None, rate: float = 1.0) -> float:
        """Wall seconds until a timeout may run out, given no reason now: the pose's (on the monotonic clock)
        or the reference's (t: simulated time now, rate: simulated seconds a wall second); at least period_s
        and at most MAX_IDLE_S."""
        left = MAX_IDLE_S
        if self.last_pose is not None:
            left = min(left, self.last_pose + self.pose_timeout_s - self.clock.monotonic())
        if t is not None and self.ref_t is not None:
            left = min(left, (self.ref_t + self.ref_timeout_s - t) / max(rate, 1e-9))
        if self.expire and t is not None and self.until is not None:
            left = min(left, (self.until - t) / max(rate, 1e-9))
        return max(self.period_s, left + 1e-3)  # just past the deadline: the reason is strictly beyond it

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(1.0)

"""A robot process: it serves run after run, each with a fresh agent (agents.agent.Agent) on its bus.

It knows only what it hears on the bus:
  robot/<id>/pose     its own pose (from the world now, from localization on a real robot)
  leader/ref          the leader's reference
  cell/<cx>/<cy>/*    the states of the robots in the 3x3 cells around its own
  world/obstacles     the static obstacles (queried once; those within range are used)
  world/clock         the clock (lock-step ticks, or the real-time epoch)
  alive/robot/*       liveliness: a robot that disappears stays a static body at its last pose
and publishes its state on its cell key, its command on robot/<id>/cmd (reliable) and a status.
The law is swarm.core.law.robot_command, the very function `swarm sim` compiles, run here without
numpy or numba (a robot process starts fast and stays small): compiled from its C transcription where
setup.py built it (swarm.core.fastlaw: the same bits, tested), else as plain Python; or the user's law
the run names (agents.control). This module imports nothing of the world: the same agent drives a
simulated or a real robot.

The agent is in layers by concern (agents.state lists them); agents.lockstep says the lock-step tick
protocol, agents.realtime the real-time step, agents.rtsafety the safety rule around the law. Here: the
process level (run_robot and its loops, the configuration and obstacles asked of the world).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, cast

from swarm.proto import keys, protocol
from swarm.core import safety
from swarm.core import runid
from swarm.core.clock import said_step
from swarm.process import name_thread, settle_heap
from agents.agent import Agent
from agents.follow import NoAnswer, RunFollower, check_run, query_until  # noqa: F401  (NoAnswer: for callers)
from agents.guard import REF_TIMEOUT_S, Guard, arena_of
from agents.state import (CLOSE_WAIT_S, DEPART_EVERY, DEPART_S, GAP_PERIODS, HEAR_GAP_PERIODS,
                          HINTS_PER_TICK, KEY_IDS_MAX, LISTEN_PERIODS, POSE_LATE_PERIODS, PROBE_S, RECENT_S,
                          RT_BODIES_TTL_S, STALE_AFTER_S, STAND_BELOW, STATUS_PERIOD_S, WAIT_TIMEOUT_S, WATCHDOG_S,
                          block)
from swarm.proto.protocol import Config
from swarm.core.wake import Runner
from swarm.core.errors import SwarmError
from swarm.net import presence

if TYPE_CHECKING:
    from collections.abc import Callable

    from swarm.drives.base import Drive

log = logging.getLogger("swarm.robot")

__all__ = ["Agent", "DriveRefused", "NoAnswer", "RobotOptions", "fetch_config", "fetch_obstacles", "run_robot", "within_limits",
           # the agent's constants (agents.state), where callers have always found them
           "CLOSE_WAIT_S", "DEPART_EVERY", "DEPART_S", "GAP_PERIODS", "HEAR_GAP_PERIODS", "HINTS_PER_TICK",
           "KEY_IDS_MAX", "LISTEN_PERIODS", "POSE_LATE_PERIODS", "PROBE_S", "RECENT_S", "RT_BODIES_TTL_S",
           "STALE_AFTER_S", "STAND_BELOW", "STATUS_PERIOD_S", "WAIT_TIMEOUT_S", "WATCHDOG_S", "block"]


class DriveRefused(SwarmError, RuntimeError):
    """A drive that cannot serve this run (a ROS 2 robot in a lock-step run)."""


# ---------------------------------------------------------------------- process level


def fetch_config(bus, fleet: str, robot_id: int, timeout_s: float, stop: threading.Event | None = None,
                 run: str | None = None) -> Config:
    """Ask the world's configuration queryable for this robot's slice (of run `run`, if given),
    retrying until timeout_s (NoAnswer)."""
    key = keys.world_config(fleet, robot_id)
    return query_until(bus, key, "config", robot_id, timeout_s, stop, what=f"the configuration of robot {robot_id}",
                       accept=None if run is None else (lambda c: c.run == run))


def fetch_obstacles(bus, fleet: str, timeout_s: float, stop: threading.Event | None = None) -> list[protocol.Obstacle]:
    msg = query_until(bus, keys.world_obstacles(fleet), "obstacles", None, timeout_s, stop, what="the obstacles")
    return list(msg.obstacles)


def within_limits(cfg: Config, limits: tuple[float, float] | None) -> Config:
    """The configuration with v_max and w_max tightened to a drive's own (its robot model's) limits: the law, its
    governor and the command clip then keep to them. No limits (None): cfg as it is; a limit of cfg's 0 is none."""
    if limits is None:
        return cfg
    v, w = limits
    return protocol.replace(cfg, v_max=v if cfg.v_max <= 0 else min(cfg.v_max, v),
                   w_max=w if cfg.w_max <= 0 else min(cfg.w_max, w))


@dataclass(frozen=True)
class RobotOptions:
    """How a robot process serves runs: built once by the command line (`swarm robot`'s flags, an inventory's row)
    or a test; run_robot takes it, or any of its fields as keywords."""

    scenario: Any = None  # this process's own scenario (swarm.core.scenario.Scenario), or None: the world's
    start_timeout: float = 60.0  # s: the world (its run, its configuration) must answer within this
    wait_timeout: float = WAIT_TIMEOUT_S  # lock-step: wall s to wait for a tick's inputs
    once: bool = False  # serve one run only
    make_drive: Callable[..., Any] | None = None  # real time: make_drive(cfg, now) -> the drive (None: simulated)
    ref_timeout: float = REF_TIMEOUT_S  # the guard: a reference extrapolated longer than this halts the robot
    pose_timeout: float = WATCHDOG_S  # the guard: a pose older than this halts the robot
    mode: str | None = None  # "lockstep" or "realtime": a run of the other mode is refused; None takes the world's
    law_file: str | None = None  # this machine's copy of the run's law, when not where the run's config says


def run_robot(bus, clock, robot_id: int, fleet: str = "default", stop: threading.Event | None = None,
              opts: RobotOptions | None = None, **fields) -> list[Agent]:
    """Serve runs as robot `robot_id` on `bus` until `stop` is set: for every run the world announces,
    a fresh agent (tick state, windows, controller) with this robot's slice of the run's scenario:
    from `scenario` (this process's own; a run of another scenario is refused: RunRefused) or from
    the world's configuration queryable. NoAnswer if no world answers within start_timeout. Returns
    the agents of the runs served (their counters). clock: swarm.core.clock (WALL in a process).
    once: serve one run only. Real time: make_drive(cfg, now) builds the drive (swarm.drives; default
    the simulated world's keys; now() is the swarm's clock) and a guard (agents.guard) halts it when
    its pose is older than pose_timeout, the reference is extrapolated longer than ref_timeout, the
    leader is lost or the emergency stop is engaged. mode ("lockstep" or "realtime", swarm robot --mode): a
    run of the other mode is refused (RunRefused); None takes the world's. law_file: this machine's copy of the
    run's law, when not where the run's config says (agents.control). These are RobotOptions's fields (`opts`,
    each overridden by a keyword of `fields`)."""
    o = replace(opts or RobotOptions(), **fields)
    scenario, start_timeout, wait_timeout, once, make_drive = o.scenario, o.start_timeout, o.wait_timeout, o.once, \
        o.make_drive
    ref_timeout, pose_timeout, mode, law_file = o.ref_timeout, o.pose_timeout, o.mode, o.law_file
    stop = stop or threading.Event()
    current: list[Agent] = []

    def on_new(run) -> None:  # on the bus's thread: the agent of the run under way ends (its loop returns)
        for a in list(current):
            a.end()

    runs = RunFollower(bus, fleet, on_new)
    mine = runid.canonical(scenario) if scenario is not None else None
    served: list[Agent] = []
    # who this process is (`swarm ps`), from the start: a robot waiting for a run has no token yet
    proc = presence.serve(bus, fleet, "robot", robot_id, run=lambda: current[0].cfg.run if current else "")
    try:
        run = runs.current(start_timeout, stop, me=("robot", robot_id))
        while not stop.is_set():
            if mine is not None and not run.scenario:
                run = runs.complete(run, start_timeout, stop)  # to name the first difference, if any
            check_run(run, mine, robot_id, mode)
            faults = None
            if scenario is not None:
                cfg = runid.robot_config(scenario, robot_id, run.lockstep, run.run, run.digest)
                faults = scenario.faults
            else:
                cfg = fetch_config(bus, fleet, robot_id, start_timeout, stop, run=run.run)
                # under faults every process reads the same schedule (the run's)
                run = runs.complete(run, start_timeout, stop)
                faults = _run_faults(run)
            obstacles = fetch_obstacles(bus, fleet, start_timeout, stop)
            drive = guard = fbus = None
            rbus = bus
            box: list[Agent] = []
            if cfg.lockstep and make_drive is not None:
                make_drive(cfg, lambda: None)  # raises DriveRefused: a real drive has no ticks
            if not cfg.lockstep:
                if faults:  # real time under faults: what this robot receives goes through the fault model
                    rbus = fbus = _fault_bus(bus, faults, cfg, fleet, clock, box)
                now = (lambda: box[0].sim_time(clock.time()) if box else None)
                drive = make_drive(cfg, now) if make_drive is not None else None
                cfg = within_limits(cfg, drive.speed_limits if drive is not None else None)
                if drive is None:
                    from swarm.drives.sim import SimDrive

                    drive = SimDrive(rbus, fleet, robot_id)
                guard = Guard(drive, clock, pose_timeout_s=pose_timeout, ref_timeout_s=ref_timeout, arena=arena_of(cfg),
                              expire=not drive.enforces_validity)
            agent = Agent(rbus, cfg, fleet, wait_timeout=wait_timeout, clock=clock, drive=drive, guard=guard,
                          faults=faults if cfg.lockstep else None, counters=fbus,
                          inline=getattr(rbus, "threaded_callbacks", False),
                          partitions=() if cfg.lockstep or not faults else faults.partitions, law_file=law_file,
                          ahead=True)
            box.append(agent)
            current[:] = [agent]
            if runs.latest is not None and runs.latest.run != run.run:
                agent.end()  # another run began while this one was being set up
            log.info("robot %d: run %s (%s, %d robots; law %s, message loops %s)", robot_id, run.run,
                     "lock-step" if run.lockstep else "real time", run.robots, agent.control.label,
                     "compiled" if protocol._wire is not None else "Python")
            try:
                agent.start(obstacles)
                settle_heap()
                if guard is not None:
                    guard.start(lambda: agent.sim_time(clock.time()), lambda: agent.speed)
                p0 = time.process_time()
                if cfg.lockstep:
                    _loop_lockstep(agent, stop)
                else:
                    _loop_realtime(agent, stop)
                agent.process_cpu_s = time.process_time() - p0  # read by the log line below, reached only from here
                if not cfg.lockstep:
                    said_step(clock, log, f"robot {robot_id}", run.run)
            finally:
                if guard is not None:
                    guard.close()
                agent.close()  # halts and closes the drive: on every way out
                if fbus is not None:
                    fbus.detach()
                current.clear()
            log.info("robot %d, run %s: %d ticks, %d skipped, %d states and %d references received, %d bad messages, "
                     "%d stale, %d duplicated, %d poses not as its states ahead said, loop CPU %.0f us a tick, "
                     "process CPU %.0f us a tick", robot_id, agent.cfg.run, agent.ticks, agent.skipped,
                     agent.states_received, agent.refs_taken, agent.bad_count(), agent.bad.stale, agent.bad.duplicates,
                     agent.mispredicted, 1e6 * agent.loop_cpu_s / max(1, agent.ticks),
                     1e6 * agent.process_cpu_s / max(1, agent.ticks))
            if not agent.cfg.lockstep:
                w = agent.held_why
                log.info("robot %d, run %s: safety rule: %d of %d commands held back (by a body %d, only away from "
                         "one %d, robots unheard %d, its promise %d), %d promises to stand, %d neighbours taken as "
                         "away, %d listened for in every cell", robot_id, agent.cfg.run, agent.held, agent.commanded,
                         w[safety.BODY], w[safety.AWAY_ONLY], w[safety.UNKNOWN], agent.held - sum(w),
                         agent._promises, agent.forgotten, agent.probed)
            served.append(agent)
            if once:
                break
            nxt = runs.next(after=run.run, stop=stop)
            if nxt is None:
                break
            run = nxt
    finally:
        runs.close()
        proc.close()
    return served


def _fault_bus(bus, faults, cfg: Config, fleet: str, clock, box: list):
    """Real time under faults: a swarm.net.faultbus.FaultBus around bus for this robot. Its holds follow the
    swarm's speed, which the agent (box[0], once made) learns from the clock."""
    from swarm.core.faulttable import FaultTable
    from swarm.net.faultbus import FaultBus

    table = FaultTable.of(faults, cfg.robots, cfg.dt)
    return FaultBus(bus, table, cfg.id, cfg.dt, fleet, speed=lambda: box[0].speed if box else 1.0, clock=clock)


def _run_faults(run):
    """The faults of a run (its scenario text), or RunRefused naming why they do not check."""
    from agents.follow import RunRefused
    from swarm.core.errors import ScenarioError

    try:
        return runid.faults_of(run.scenario, run.robots, f"run {run.run}")
    except ScenarioError as e:
        raise RunRefused(f"run {run.run}'s faults do not check: {e}") from None


def _loop_lockstep(agent: Agent, stop: threading.Event) -> None:
    """Lock-step: the ticks as they become due. Inline (agent.kick a Runner), the bus's threads run them and
    this thread wakes only to close what they released, and for a tick overdue (its deadline); a tick run
    on another thread while this one looks (next_wakeup() then says 0) is waited for in short naps."""
    cpu = time.thread_time
    runner = agent.kick if isinstance(agent.kick, Runner) else None
    least = 0.0 if runner is None else 0.002
    try:
        while not stop.is_set() and not agent.ended:
            agent.wake.wait(min(0.2, max(least, agent.next_wakeup())))
            c0 = cpu()
            agent.wake.clear()
            if runner is None:
                while agent.tick_lockstep():  # a tick done; the next pose may already be here
                    pass
            else:
                agent.close_released()
                runner.set()  # a tick overdue (or one due that no bus thread runs now)
                if runner.error is not None:
                    raise runner.error
            agent.loop_cpu_s += cpu() - c0
    finally:
        if runner is not None:
            agent.loop_cpu_s += runner.cpu_s  # the ticks' CPU, wherever they ran


def _loop_realtime(agent: Agent, stop: threading.Event) -> None:
    """Real time: a command for every new pose (the pose stream sets the control rate: the world's
    control period now, localization's rate on a real robot), at the agent's own clock's time.
    No new pose, no command, and the drive's watchdog stops the robot; but with a periodic drive (the
    simulated world's) a pose that has not come POSE_LATE_PERIODS periods after the last one is taken
    as lost, and the step goes on from the last pose advanced by its own command (Agent.late_due).
    The loop blocks on its drive's pose inbox: zenoh's receiving thread runs no Python and hands the
    pose straight to this thread (no callback, no GIL hand-over, no event). A helper thread wakes it on
    stop, and when a step without a pose is due. Inline (agent.kick a Runner: the simulated drive on
    zenoh, no faults), the drive's pose callback runs the step on zenoh's thread and the helper runs a step
    without a pose; this thread only closes what the steps let go, and returns on stop."""
    done = threading.Event()
    runner = agent.kick if isinstance(agent.kick, Runner) else None
    waker = threading.Thread(target=_watch, args=(stop, done, agent.drive if runner is None else _Kick(agent), agent),
                             daemon=True, name=f"robot-{agent.id}-waker")
    waker.start()
    cpu = time.thread_time
    try:
        while not stop.is_set() and not agent.ended:
            if runner is None:
                got = cast("Drive", agent.drive).wait()
                c0 = cpu()
                agent.step_realtime(got)
            else:  # the steps run on the drive's callback (and the waker's thread): wake for stop and closing
                agent.wake.wait(0.2)
                c0 = cpu()
                agent.wake.clear()
                agent.close_released()
                if runner.error is not None:
                    raise runner.error
            agent.loop_cpu_s += cpu() - c0
    finally:
        done.set()
        if agent.late_timer is not None:
            agent.late_timer.stop()  # the waker's wait returns now
        waker.join(1.0)
        if runner is not None:
            agent.loop_cpu_s += runner.cpu_s  # the steps' CPU, wherever they ran


def _watch(stop: threading.Event, done: threading.Event, box, agent: Agent) -> None:
    """The real-time loop's helper: wake it (box.wake()) on stop, and when a step without a pose is due."""
    name_thread("waker")
    woke_for = None
    timer = agent.late_timer
    while not done.is_set():
        try:
            agent.report_idle()
        except Exception as e:  # the session is closing: the run is over anyway
            log.debug("robot %d: no idle fault report: %s", agent.id, e)
        due = agent.late_due()
        if due is None:
            left = 0.2
        elif due == woke_for:  # the loop has not taken that one yet: look again in half a period
            left = min(0.2, agent._period_wall() / 2)
        else:
            left = min(0.2, max(0.0, due - agent.clock.monotonic()))
        if timer is not None:
            # the agent arms the timer with each new due (every pose moves it a period on): the wake-ups that
            # find it moved stay in C, without the GIL; stop is seen within 0.2 s
            if due is None or due == woke_for:
                time.sleep(left)
            else:
                timer.wait(0.2)
            if stop.is_set() or agent.ended:
                _wake(box)
                return
        elif stop.wait(left) or agent.ended:
            _wake(box)
            return
        if due is not None and due != woke_for and agent.late_due() == due and agent.clock.monotonic() >= due:
            woke_for = due
            _wake(box)


class _Kick:
    """Real time inline: what the waker wakes: the step (a step without a pose may be due) and the loop (stop)."""

    def __init__(self, agent: Agent) -> None:
        self.agent = agent

    def wake(self) -> None:
        self.agent.kick.set()
        self.agent.wake.set()


def _wake(box) -> None:
    try:
        box.wake()
    except Exception as e:  # the session is already closing: the loop is on its way out anyway
        log.debug("could not wake the robot loop: %s", e)

"""The robot agent: one robot's decentralized controller (agents.robot runs it as a process).

Agent assembles the layers of agents.state (its docstring lists them) and adds what needs all of them:
start() (the subscriptions and the liveliness token), close(), and, made once from the run's mode, the
inline runner of a tick and the compiled sink of neighbour states.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, cast

from swarm.proto import keys, protocol
from swarm.core.wake import Runner
from swarm.core.clock import WALL
from swarm.proto.protocol import Config
from agents.state import CLOSE_WAIT_S, WAIT_TIMEOUT_S
from agents.lockstep import Lockstep
from agents.realtime import Realtime

if TYPE_CHECKING:
    from swarm.drives.base import Drive

log = logging.getLogger("swarm.robot")


class Agent(Lockstep, Realtime):
    """One robot's controller on a bus; it subscribes and publishes on its own (start(), then a loop).

    Thread model: bus callbacks (the _on_*_msg methods) run on the bus's receiving thread: they
    validate the message, update what the agent knows under `lock`, and set `kick` when there is
    something to do (a new tick, or a tick whose inputs are complete). By default `kick` is `wake`, the
    loop thread's, and the loop thread does every bus call (publish, move subscriptions, drain inboxes).
    Inline (no faults, on zenoh: run_robot), `kick` is a Runner that computes the tick on the callback's
    own thread at once (lock-step; in real time the simulated drive's pose callback runs the step): no
    loop thread woken for it (docs/performance.md, "A tick on the thread its message came on"); the loop thread then only closes the subscriptions a tick
    let go (_release) and computes a lock-step tick that is overdue.
    Lock-step takes everything through callbacks (its wait rule needs each state as it arrives); its
    neighbour states through a compiled sink where it was built (swarm.proto._wire.StateSink: the same
    rules as _on_state_msg, which gets anything but their common case). Real time uses callbacks only
    for liveliness and the clock: the loop blocks on its pose inbox and drains the reference and cell
    inboxes itself (take_poses, _take_inboxes).
    """

    def __init__(self, bus, cfg: Config, fleet: str = "default", wait_timeout: float = WAIT_TIMEOUT_S,
                 clock=WALL, drive: Drive | None = None, guard=None, faults=None, counters=None, inline: bool = False,
                 partitions=(), law_file: str | None = None, ahead: bool = False):
        """inline (zenoh's bus, no faults): a lock-step tick runs on the bus thread whose message made it due
        (its pose, the last state it waited for), and a real-time step on the thread of its simulated drive's
        pose, instead of waking the loop thread for it (`kick`, a swarm.core.wake.Runner; only on a bus that
        calls another session's messages on threads of its own: zenoh's). The other arguments: AgentState."""
        super().__init__(bus, cfg, fleet, wait_timeout, clock, drive, guard, faults, counters, partitions, law_file, ahead)
        drive = self.drive
        if inline and self.view is None and counters is None and (cfg.lockstep or (drive is not None and drive.takes_callback)):
            self.kick = Runner(self._ticks if cfg.lockstep else self._step_inline, self.wake)
        # lock-step, no faults: neighbour states taken in C on the bus's thread (swarm/proto/_wire_states.c, StateSink;
        # anything but the common case goes to _on_state_msg)
        wire = protocol._wire
        if wire is not None and cfg.lockstep and self.view is None and hasattr(bus, "subscribe_sink"):
            self._state_sink = wire.StateSink(self.id, self._key_ids, self._dec_state, self._on_state_msg,
                                              self._sink_error, self.lock.acquire, self.lock.release, self.kick.set,
                                              self._due, self.table, self.w_state, self.waiting)

    def start(self, obstacles: list[protocol.Obstacle] | None = None) -> None:
        """Subscribe (own pose, reference, clock, liveliness, the cells around the start pose),
        then declare this robot's liveliness token: whoever sees the token can count on them."""
        f = self.fleet
        self.set_obstacles(obstacles or [])
        if self.cfg.lockstep:
            self._inputs = [self.bus.subscribe(key, fn) for key, fn in self._lockstep_inputs()]
        elif isinstance(self.kick, Runner):  # its drive's poses to a callback that runs the step (_step_inline)
            cast("Drive", self.drive).start(self._on_drive_poses)  # real time always has one
            self._poses_by_callback = True
            self._ref_inbox = self.bus.inbox(self._ref_key)
            self._handles.append(self._ref_inbox)
        else:  # the loop waits on its drive's poses and drains the other inboxes (see _loop_realtime)
            cast("Drive", self.drive).start()
            self._ref_inbox = self.bus.inbox(self._ref_key)
            self._handles.append(self._ref_inbox)
        self._handles.append(self.bus.subscribe(keys.estop(f), self._on_estop_msg))
        if not self.cfg.lockstep or self.view is None:  # robots standing still (lock-step under faults: an input)
            self._handles.append(self.bus.subscribe(keys.world_bodies(f), self._on_bodies_msg))
        if self.cfg.lockstep and (self.view is None or self.view.active(0) or self.view.returns()):
            # tick 0 waits for every robot's state_0, heard in every cell (agents.lockstep): subscribed before the
            # token, so before anyone's state_0 (the world sends pose_0 once it has every token); under faults it
            # also serves a return tick, the first tick of the process of a restart among them. A robot the
            # schedule has away from tick 0 for good runs no tick: it would hear every state of the run for nothing
            self._listen_all(True)
        self._clock_sub = self.bus.subscribe(keys.world_clock(f), self._on_clock_msg)
        self._handles.append(self.bus.watch_alive(keys.alive_any(f), self._on_alive_msg))
        self._move_cells(self.cfg.x, self.cfg.y)
        self._handles.append(self.bus.token(keys.alive(f, "robot", self.id)))  # its process says who it is: run_robot

    def close(self) -> None:
        """Release everything; a drive is halted and closed (on every way out: the end of a run, Ctrl-C,
        SIGTERM, an exception). Inline, no tick runs on a bus thread from here on (after one under way)."""
        if isinstance(self.kick, Runner) and not self.kick.stop(CLOSE_WAIT_S):
            log.warning("robot %d: a tick on the bus's thread still runs after %g s; closing all the same",
                        self.id, CLOSE_WAIT_S)
        self.close_released()
        if self.drive is not None:
            try:
                self.drive.close()
            except Exception as e:  # the session may be gone already: nothing left to tell the body
                log.warning("robot %d: closing the drive: %s", self.id, e)
        self.drop_clock()
        self._listen_all(False)
        for h in self._inputs:
            h.close()
        self._inputs = []
        for h in list(self._cells.values()) + list(self._probes.values()) + self._handles[::-1]:
            h.close()
        self._cells.clear()
        self._probes.clear()
        self._handles.clear()

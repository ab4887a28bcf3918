"""The emergency stop as the world sees it: each engage and release logged with its reason, told on world/events
(the recording, the report and the viewers show it) and counted in the run's metrics (`estops`).

    watch = EstopLog(bus, fleet, now=lambda: (world.t, world.k))
    watch.start()
    ...
    watch.metrics()   -> {"estops": {"engaged": 1, "released": 1, "events": [{"t": 12.3, "engaged": true, ...}]}}

The robots obey the stop (agents.robot, agents.guard); this only reports it. An operator repeats each message
for a while (`swarm stop --repeat-s`): only a change (engaged <-> released) counts. As the robots do
(swarm.proto.window.StopOrder, on this machine's clock), an engage is taken whatever its t and seq; a release
only when it comes after every engage taken.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Callable

from swarm.proto import keys, protocol, window
from swarm.proto.protocol import ProtocolError

log = logging.getLogger("swarm.world")

EVENTS_KEPT = 100  # the metrics list at most this many changes (the counts are whole)


class EstopLog:
    def __init__(self, bus, fleet: str, now: Callable[[], tuple[float, int]], span: float = window.ESTOP_SPAN_S,
                 wall: Callable[[], float] = time.time) -> None:
        self.bus, self.fleet, self.now, self.wall = bus, fleet, now, wall
        self.bad = protocol.BadMessages(log)
        self.engaged: str | None = None  # the reason of the stop in force, None while released
        self.counts = {"engaged": 0, "released": 0}
        self.events: list[dict] = []
        self.order = window.StopOrder(span)  # the robots' span (window.ESTOP_SPAN_S): the same order as theirs
        self._lock = threading.Lock()
        self._handle = None

    def start(self) -> None:
        self._handle = self.bus.subscribe(keys.estop(self.fleet), self._on)

    def _on(self, key: str, data: bytes) -> None:
        try:
            e = protocol.decode(data, "estop")
        except ProtocolError as err:
            self.bad.reject(key, err)
            return
        with self._lock:
            act, verdict = self.order.take(e.engaged, e.t, e.seq, self.wall())
            if verdict == window.JUMP:
                self.bad.verdict(key, verdict, "the emergency stop's t")
            if not act or (self.engaged is not None) == e.engaged:
                return  # a repeat, another operator's, or a release older than the engage in force
            self.engaged = (e.reason or "no reason given") if e.engaged else None
            kind = "engaged" if e.engaged else "released"
            self.counts[kind] += 1
            t, seq = self.now()
            if len(self.events) < EVENTS_KEPT:
                self.events.append({"t": round(t, 3), "engaged": e.engaged, "reason": e.reason})
        log.warning("emergency stop %s at t = %.3f s%s", "ENGAGED" if e.engaged else "released", t,
                    f": {e.reason}" if e.reason else "")
        self.bus.put(keys.world_events(self.fleet), protocol.encode(protocol.Event(
            t=max(0.0, t), seq=max(0, seq), event="estop" if e.engaged else "estop_release", robots=(),
            detail=e.reason)), reliable=True)

    def metrics(self) -> dict:
        """The run's `estops` (docs/metrics.md): the changes counted, and the first EVENTS_KEPT of them."""
        with self._lock:
            return {"estops": {**self.counts, "events": list(self.events)}}

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None

"""Following runs: long-lived robots and leaders serve one run after another.

    runs = RunFollower(bus, fleet, on_new=callback)   # subscribes to world/run
    run = runs.current(timeout_s, stop)               # the run under way (asks the world's queryable)
    runs.next(after=run.run, stop=stop)               # block until another run begins (None on stop)
    check_run(run, my_digest, my_toml, robot_id)      # RunRefused if this process must not take part

A world announces every run on world/run (a new id, the digest of its scenario) and serves it on the
same key (with the scenario's canonical TOML). A process that follows runs starts afresh on each one:
new tick state, windows and controller. A process given its own scenario takes part only in a run
of the same scenario: otherwise it refuses, naming the first difference.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import cast

from swarm.core import runid
from swarm.net import presence
from swarm.proto import keys, protocol
from swarm.proto.protocol import ProtocolError, Run
from swarm.core.errors import SwarmError

log = logging.getLogger("swarm.follow")
SAY_S = 3.0  # s: a process still without the world's answer says what is on the router instead


class NoAnswer(SwarmError, RuntimeError):
    """Nobody answered a query in time."""


class RunRefused(SwarmError, RuntimeError):
    """This process must not take part in the run (another scenario, an id outside it)."""


def query_until(bus, key: str, kind: str, key_id, timeout_s: float, stop, what: str, accept=None, why=None):
    """Ask a queryable until a valid reply comes (and accept(msg) holds), or raise NoAnswer after timeout_s.
    why(): what is on the router instead, said once after SAY_S without an answer (and in the NoAnswer)."""
    end = time.monotonic() + timeout_s
    say_at = time.monotonic() + SAY_S if why is not None else math.inf
    last_error = "no reply"
    hint = "is the world running on this fleet and router?"
    while True:
        if time.monotonic() >= say_at:
            say_at, hint = math.inf, _hint(why, hint)
            log.warning("no answer for %s after %g s: %s; waiting up to %.0f s more (swarm ps lists what is on the "
                        "router)", what, SAY_S, hint, max(0.0, end - time.monotonic()))
        left = end - time.monotonic()
        for rkey, payload in bus.query(key, timeout_s=max(0.05, min(1.0, left))):
            try:
                msg = protocol.decode(payload, kind, key_id)
            except ProtocolError as e:
                error = f"bad reply on {rkey}: {e}"
                if error != last_error:  # said once, not at every retry: a world's bad reply is no network hiccup
                    log.warning("%s while asking for %s (asking again until %g s have passed)", error, what, timeout_s)
                last_error = error
                continue
            if accept is None or accept(msg):
                return msg
            last_error = "a reply of another run"
        if time.monotonic() >= end or (stop is not None and stop.is_set()):
            if why is not None and say_at == math.inf:  # said before: what is there now
                hint = _hint(why, hint)
            raise NoAnswer(f"no answer for {what} on {key} within {timeout_s:g} s ({last_error}); {hint}")
        if stop is not None:
            stop.wait(0.1)
        else:
            time.sleep(0.1)


def _hint(why, otherwise: str) -> str:
    """why(), or `otherwise` when it cannot say (the session went, a reply that does not decode)."""
    try:
        return why()
    except Exception as e:  # a hint must never hide the error it explains
        log.debug("what is on the router: %s", e)
        return otherwise


class RunFollower:
    """The runs a world announces, as they come (the callback runs on the bus's thread: keep it short)."""

    def __init__(self, bus, fleet: str, on_new=None) -> None:
        self.bus, self.fleet, self.on_new = bus, fleet, on_new
        self.lock = threading.Condition()
        self.latest: Run | None = None
        self.bad = protocol.BadMessages(log)
        self._sub = bus.subscribe(keys.world_run(fleet), self._on_run)

    def _on_run(self, key: str, data: bytes) -> None:
        try:
            run = protocol.decode(data, "run")
        except ProtocolError as e:
            self.bad.reject(key, e)
            return
        self._adopt(run)

    def _adopt(self, run: Run) -> None:
        with self.lock:
            if self.latest is not None and self.latest.run == run.run:
                if not self.latest.scenario and run.scenario:
                    self.latest = run  # the same run, now with its scenario text
                return
            self.latest = run
            self.lock.notify_all()
        if self.on_new is not None:
            self.on_new(run)

    def current(self, timeout_s: float, stop: threading.Event | None = None, me: tuple[str, int] | None = None) -> Run:
        """The run under way, with its scenario text (the world's queryable), or NoAnswer (naming what is on the
        router instead; me: this process's role and id, left out of that)."""
        run = query_until(self.bus, keys.world_run(self.fleet), "run", None, timeout_s, stop, what="the current run",
                          why=lambda: presence.why_no_world(self.bus, self.fleet, me))
        self._adopt(run)
        with self.lock:
            return cast(Run, self.latest)  # _adopt set it

    def next(self, after: str, stop: threading.Event) -> Run | None:
        """Block until a run other than `after` is announced; None if stop is set first."""
        with self.lock:
            while not stop.is_set():
                if self.latest is not None and self.latest.run != after:
                    return self.latest
                self.lock.wait(0.2)
        return None

    def complete(self, run: Run, timeout_s: float, stop: threading.Event | None = None) -> Run:
        """`run` with its scenario text (a publication carries none): ask the world for it."""
        if run.scenario:
            return run
        got = query_until(self.bus, keys.world_run(self.fleet), "run", None, timeout_s, stop,
                          what=f"run {run.run}", accept=lambda r: r.run == run.run)
        return got

    def close(self) -> None:
        self._sub.close()


def check_run(run: Run, mine: str | None, robot_id: int | None = None, mode: str | None = None) -> None:
    """Refuse (RunRefused) a run this process must not take part in: a robot id outside the run's
    scenario, a run of another mode than `mode` ("lockstep" or "realtime"; None: any), or (mine: this
    process's own scenario as canonical TOML) a run of another scenario."""
    if robot_id is not None and robot_id >= run.robots:
        raise RunRefused(f"robot {robot_id} is not in run {run.run}: its scenario has {run.robots} robots "
                         f"(ids 0..{run.robots - 1})")
    if mode is not None and run.lockstep != (mode == "lockstep"):
        raise RunRefused(f"run {run.run} is {'lock-step' if run.lockstep else 'real time'} and this robot was started "
                         f"with --mode {mode}; give the world's mode, or leave --mode out")
    if mine is None:
        return
    import hashlib

    if hashlib.sha256(mine.encode("utf-8")).hexdigest() == run.digest:
        return
    diff = runid.first_difference(mine, run.scenario) if run.scenario else None
    raise RunRefused(f"run {run.run} is of another scenario than this process's (digest {run.digest[:12]} against "
                     f"{hashlib.sha256(mine.encode('utf-8')).hexdigest()[:12]})"
                     + (f"; first difference: {diff}" if diff else "")
                     + "; give the same scenario and flags as the world"
                     + (", or none (the robot then takes the world's)" if robot_id is not None else ""))

"""Recording a run into one MCAP file (JSON messages with JSON schemas: Foxglove opens it as is).

    rec = Recorder("run.mcap", scenario, record_hz=20.0, source="lockstep")
    br = BusRecorder(bus, fleet, rec)           # live: subscribes, decodes, derives events
    ...
    br.close(metrics)                           # writes the metrics, finishes the file

    record_simulation("run.mcap", scenario, result, record_hz=20.0)   # the same file from `swarm sim`

Channels (docs/recording.md): /scenario (once, first), /world/snapshot, /leader/ref, /robot/cmd,
/robot/status, /events, /faults, /metrics (once, last). /faults holds the fault events as the world
and `swarm up` told them on world/events (or, for `swarm sim`, as the fault schedule has them:
swarm.core.faults.timeline), one message each, never decimated. Time base: every message's log_time and publish_time
are nanoseconds of *simulated* time since the run's t = 0 (not wall-clock time); the scenario
message is at 0, the metrics at the last recorded time.

record_hz decimates snapshots, references, commands and statuses in simulated time: with
every = max(1, round(1 / (record_hz * dt))) control steps, a message is kept at the first time at or
after each multiple of every * dt (per robot for commands and statuses), which in lock-step is
exactly the steps the in-process simulator samples (k % every == 0); the first message, the final
step and the last snapshot are always kept. record_hz 0 or None keeps every message. Events are
derived from every message received, never from the decimated ones only.

Cost: a bus callback only appends the raw payload to a deque; one worker thread decodes
(swarm.proto.protocol.decode), derives the events and writes (bench/record_cost.py measures it).

Crashes: MCAP keeps its index and statistics in a footer written at the end, so a killed run's file
has none. The writer therefore closes its chunk and flushes the file at least every FLUSH_S wall
seconds (and right after the scenario): a run killed at any moment leaves every message up to the
last flush readable, in complete chunks that swarm.view.report reads sequentially.
"""

from __future__ import annotations

import collections
import json
import logging
import math
import threading
import time
from pathlib import Path

import numpy as np

from swarm.proto import keys, protocol, window
from swarm.core import kinematics
from swarm.proto.protocol import EVENTS as FAULT_EVENTS
from swarm.proto.protocol import Cmd, ProtocolError, Ref, Snapshot, Status
from swarm.core.geometry import pairs_within
from swarm.core.faultgen import TIME_EPS
from swarm.core.faultsim import WATCHDOG_S
from swarm.core.scenario import Scenario
from swarm.view.events import Event as Event, EventDeriver as EventDeriver
from swarm.view.faultmarks import FaultMarks
from swarm.core.errors import SwarmError

log = logging.getLogger("swarm.record")

DEFAULT_RECORD_HZ = 20.0
STATUS_PERIOD_S = 0.1  # record_simulation writes statuses at the agents' status rate (agents/state.py)
MAX_BAD_EVENTS = 100  # bad messages beyond this are counted, not written one by one
MAX_PENDING = 200_000  # BusRecorder: received messages not yet written; a callback waits beyond this
MAX_PENDING_BYTES = 64 << 20  # BusRecorder: and their bytes (a flood of 64 KiB messages: 200 000 would be 13 GB)
SNAPSHOT_ROW_BYTES = 128  # a snapshot's row is at most 84 bytes encoded: one beyond 256 + this a robot is no
# snapshot of the run's robots, and is dropped (counted bad) before it is queued or decoded (an 8 MB one cost
# 0.6 s of decoding, and a flood of them a gigabyte)
_OVERSIZED = "oversized snapshot"  # the queue's topic for one (its payload: the size, in decimal)
POLL_S = 0.02  # BusRecorder: the worker's wake-up period [wall s]
FLUSH_S = 1.0  # Recorder: wall seconds between chunk flushes (what a killed run loses at most)

TOPIC_SCENARIO = "/scenario"
TOPIC_SNAPSHOT = "/world/snapshot"
TOPIC_REF = "/leader/ref"
TOPIC_CMD = "/robot/cmd"
TOPIC_STATUS = "/robot/status"
TOPIC_EVENTS = "/events"
TOPIC_FAULTS = "/faults"
TOPIC_METRICS = "/metrics"

EVENT_KINDS = ("freeze_start", "freeze_end", "collision", "robot_dead", "robot_alive", "robot_stopped",
               "robot_resumed", "snapshots_missed", "bad_message")

# Keys of the metrics contract (docs/design.md, Metrics) that every metrics message carries (extra keys are allowed).
METRIC_KEYS = ("robots", "obstacles", "duration_s", "dt", "seed", "converged_at_s", "final_position_error_max_m",
               "final_orientation_error_max_rad", "min_robot_distance_m", "min_obstacle_distance_m", "collisions",
               "last_freeze_end_s", "wall_s", "messages_dropped", "cmd_misses", "bad_messages", "interrupted")


class RecordError(SwarmError, ValueError):
    """A recording that cannot be written (bad record_hz, a sample grid that does not fit...)."""


# --------------------------------------------------------------------------- schemas

_NUM, _INT, _BOOL, _STR = {"type": "number"}, {"type": "integer"}, {"type": "boolean"}, {"type": "string"}


def _arr(item: dict) -> dict:
    return {"type": "array", "items": item}


def _schema(title: str, description: str, props: dict, optional: tuple[str, ...] = (), extra: bool = False) -> dict:
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "description": description,
            "type": "object", "properties": props, "required": [k for k in props if k not in optional],
            "additionalProperties": extra}


# Metrics that may be null (docs/design.md, Metrics): not declared below, since a JSON Schema type list such as
# ["number", "null"] is valid JSON Schema but Foxglove's schema reader refuses it (one type per field).
NULLABLE_METRICS = ("converged_at_s", "final_position_error_max_m", "final_orientation_error_max_rad",
                    "min_robot_distance_m", "min_obstacle_distance_m", "last_freeze_end_s")

# topic -> (schema name, JSON schema). One "type" per property (what Foxglove reads); a property that can
# be absent (optional) is left out of the message rather than written as null.
SCHEMAS: dict[str, tuple[str, dict]] = {
    TOPIC_SCENARIO: ("swarm.Scenario", _schema("swarm.Scenario", "The run's scenario, once at t = 0: `toml` is the "
                     "resolved scenario file (swarm.core.scenario_file.to_toml), enough to rebuild it exactly; `fleet` "
                     "only for live runs.", {
                         "name": _STR, "robots": _INT, "obstacles": _INT, "dt": _NUM, "duration": _NUM, "seed": _INT,
                         "r": _NUM, "R": _NUM, "source": _STR, "record_hz": _NUM, "record_every": _INT,
                         "fleet": _STR, "toml": _STR}, optional=("fleet",))),
    TOPIC_SNAPSHOT: ("swarm.Snapshot", _schema("swarm.Snapshot", "Every robot at one step, columns indexed like "
                     "`id`: pose x, y [m], theta [rad]; v [m/s], w [rad/s] the command the world applies; "
                     "stopped (watchdog), alive (liveliness), frozen (the robot's newest reported freeze flag).", {
                         "t": _NUM, "seq": _INT, "id": _arr(_INT), "x": _arr(_NUM), "y": _arr(_NUM),
                         "theta": _arr(_NUM), "v": _arr(_NUM), "w": _arr(_NUM), "stopped": _arr(_BOOL),
                         "alive": _arr(_BOOL), "frozen": _arr(_BOOL)})),
    TOPIC_REF: ("swarm.Ref", _schema("swarm.Ref", "The leader's live reference.", {
        "t": _NUM, "seq": _INT, "x": _NUM, "y": _NUM, "theta": _NUM, "v": _NUM, "w": _NUM})),
    TOPIC_CMD: ("swarm.Cmd", _schema("swarm.Cmd", "Robot `id`'s command computed at t: v [m/s], w [rad/s].", {
        "t": _NUM, "seq": _INT, "id": _INT, "v": _NUM, "w": _NUM})),
    TOPIC_STATUS: ("swarm.Status", _schema("swarm.Status", "Robot `id`'s status: errors against the live "
                   "reference, freeze flag, neighbours known, stale neighbours, bad messages it dropped.", {
                       "t": _NUM, "id": _INT, "ex": _NUM, "ey": _NUM, "etheta": _NUM, "frozen": _BOOL,
                       "neighbours": _INT, "stale": _INT, "bad": _INT})),
    TOPIC_EVENTS: ("swarm.Event", _schema("swarm.Event", "Something that happened at t. kind: " + ", ".join(EVENT_KINDS)
                   + ". robot/other are robot ids, obstacle an obstacle index, distance [m] (collisions); each only "
                   "when it applies.", {
                       "t": _NUM, "kind": {"type": "string", "enum": list(EVENT_KINDS)}, "robot": _INT,
                       "other": _INT, "obstacle": _INT, "distance": _NUM, "detail": _STR},
                   optional=("robot", "other", "obstacle", "distance"))),
    TOPIC_FAULTS: ("swarm.FaultEvent", _schema("swarm.FaultEvent", "A fault event at t (the world/events message, "
                   "docs/protocol.md): kill, restart, hang, resume (scheduled process faults of the robots named), "
                   "partition, partition_end (robots: those cut off from the world's group), signal (a signal "
                   "swarm up sent to the robots named); seq the tick (lock-step) or period; detail a readable line.", {
                       "t": _NUM, "seq": _INT, "event": {"type": "string", "enum": list(FAULT_EVENTS)},
                       "robots": _arr(_INT), "detail": _STR})),
    TOPIC_METRICS: ("swarm.Metrics", _schema("swarm.Metrics", "The run's metrics (docs/design.md, Metrics), exactly "
                    "the metrics JSON (extra keys included); written once at the end. Also there, as a number or "
                    "null: " + ", ".join(NULLABLE_METRICS) + ".", {
                        "robots": _INT, "obstacles": _INT, "duration_s": _NUM, "dt": _NUM, "seed": _INT,
                        "collisions": _INT, "wall_s": _NUM, "messages_dropped": _INT, "cmd_misses": _INT,
                        "bad_messages": _INT, "interrupted": _BOOL}, extra=True)),
}
TOPICS = tuple(SCHEMAS)


# --------------------------------------------------------------------------- decimation


def record_every(record_hz: float | None, dt: float) -> int:
    """Control steps between kept samples for record_hz [Hz] (0 or None: every step)."""
    if record_hz is None or record_hz == 0:
        return 1
    if isinstance(record_hz, bool) or not (math.isfinite(record_hz) and record_hz > 0):
        raise RecordError(f"record_hz must be a number > 0 (or 0 for every step), got {record_hz!r}")
    return max(1, int(round(1.0 / (record_hz * dt))))


def record_period(record_hz: float | None, dt: float) -> float:
    """Simulated seconds between kept samples: what to give sim.Simulation(scn, record_period=...)."""
    return record_every(record_hz, dt) * dt


class _Grid:
    """Keeps a message at the first time at or after each multiple of `period` (None: every message)."""

    __slots__ = ("period", "due", "tol")

    def __init__(self, period: float | None, dt: float):
        self.period = period
        self.due = -math.inf
        self.tol = 1e-6 * dt

    def keep(self, t: float) -> bool:
        if self.period is None:
            return True
        if t < self.due - self.tol:
            return False
        self.due = (math.floor(t / self.period + 1e-6) + 1) * self.period
        return True


def _ns(t: float) -> int:
    """log_time of simulated time t [s]: integer nanoseconds, clamped at 0 (MCAP times are unsigned)."""
    return max(0, int(round(t * 1e9)))


def _jbool(b) -> str:
    return "true" if b else "false"


# --------------------------------------------------------------------------- the writer


class Recorder:
    """One MCAP file of one run. Thread-safe: every method takes one lock (calls are short).

    path: the file (overwritten); scenario: the run's Scenario (written first, as TOML);
    record_hz: samples per simulated second (0 or None: every step); source: "sim", "lockstep",
    "realtime" or "live" (written in /scenario); fleet: the zenoh fleet name, if any;
    status_period: simulated seconds between kept statuses of a robot (None: as record_hz);
    presampled: the caller already picked the samples (record_simulation): snapshots, references and
    commands are all written, record_hz is only noted in /scenario.
    flush_s: wall seconds between chunk flushes (the most a killed run loses; None: a chunk is closed
    only when it holds chunk_size bytes, and a killed run loses up to that); clock: wall time [s].
    """

    def __init__(self, path, scenario: Scenario, record_hz: float | None = DEFAULT_RECORD_HZ,
                 source: str = "live", fleet: str | None = None, status_period: float | None = None,
                 presampled: bool = False, chunk_size: int = 1 << 20, flush_s: float | None = FLUSH_S,
                 clock=time.monotonic):
        from mcap.writer import CompressionType, Writer

        from swarm.core import scenario_file

        self.path = Path(path)
        self.scenario = scenario
        self.every = record_every(record_hz, scenario.dt)
        self.period = None if self.every == 1 else self.every * scenario.dt
        self.record_hz = float(record_hz or 0.0)
        self.status_period = self.period if status_period is None else float(status_period)
        self._final_t = scenario.steps * scenario.dt  # the final step is always kept
        self._tol = 1e-6 * scenario.dt
        self._lock = threading.Lock()
        self._grid_period = None if presampled else self.period
        self._snap_grid = _Grid(self._grid_period, scenario.dt)
        self._ref_grid = _Grid(self._grid_period, scenario.dt)
        self._cmd_grid: dict[int, _Grid] = {}
        self._status_grid: dict[int, _Grid] = {}
        self._held: tuple | None = None  # the newest snapshot not written (written at close: always keep the last)
        self.last_t = 0.0
        self.counts = {topic: 0 for topic in TOPICS}
        self.closed = False
        self._flushed = clock()
        if flush_s is not None and not (math.isfinite(flush_s) and flush_s > 0):
            raise RecordError(f"flush_s must be a number > 0 (or None), got {flush_s!r}")
        self.flush_s, self._clock = flush_s, clock
        self.flushes = 0  # chunks closed by the flush period
        try:
            self._file = open(self.path, "wb")
        except OSError as e:
            raise RecordError(f"{self.path}: cannot write the recording: {e.strerror or e}") from None
        try:
            self._w = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
            self._w.start(profile="", library="swarm")
            self._ch = {}
            for topic, (name, schema) in SCHEMAS.items():
                sid = self._w.register_schema(name, "jsonschema", json.dumps(schema).encode())
                self._ch[topic] = self._w.register_channel(topic, "json", sid)
            self._w.add_metadata("swarm", {"source": source, "record_hz": repr(self.record_hz),
                                           "record_every": str(self.every), "fleet": fleet or "",
                                           "time_base": "log_time = simulated time since t = 0, in ns"})
            scn = scenario
            self._put(TOPIC_SCENARIO, 0.0, json.dumps({
                "name": scn.name, "robots": scn.n, "obstacles": len(scn.obstacles), "dt": scn.dt,
                "duration": scn.duration, "seed": scn.seed, "r": scn.r, "R": scn.R, "source": source,
                "record_hz": self.record_hz, "record_every": self.every, **({"fleet": fleet} if fleet else {}),
                "toml": scenario_file.to_toml(scn)}))
            self._flush()  # a file killed at once still says what it is
        except BaseException:
            self._file.close()
            raise

    # -- low level

    def _put(self, topic: str, t: float, text: str, seq: int = 0) -> None:
        ns = _ns(t)
        self._w.add_message(self._ch[topic], ns, text.encode(), ns, seq)
        self.counts[topic] += 1
        if t > self.last_t:
            self.last_t = t
        self._flush_if_due()

    def _flush_if_due(self) -> None:
        if self.flush_s is not None and self._clock() - self._flushed >= self.flush_s:
            self._flush()
            self.flushes += 1

    def flush_if_due(self) -> None:
        """Flush if FLUSH_S has passed since the last flush: for a writer that may stay idle (a stalled
        run), so that what it wrote before is on disk when it is killed."""
        with self._lock:
            if not self.closed:
                self._flush_if_due()

    def _flush(self) -> None:
        """Close the chunk in progress and hand everything to the OS (survives a SIGKILL, not a power cut)."""
        self._w.flush()
        self._flushed = self._clock()

    def _keep(self, grid: _Grid, t: float) -> bool:
        return grid.keep(t) or t >= self._final_t - self._tol

    def _check_open(self) -> None:
        if self.closed:
            raise RecordError(f"{self.path}: the recording is closed")

    # -- messages

    def snapshot(self, t: float, seq: int, ids, x, y, theta, v, w, stopped, alive, frozen) -> bool:
        """One world snapshot, columns of plain lists (or arrays) indexed like ids; True if written now."""
        with self._lock:
            self._check_open()
            if not self._keep(self._snap_grid, t):
                self._held = (t, seq, ids, x, y, theta, v, w, stopped, alive, frozen)
                return False
            self._held = None
            self._write_snapshot(t, seq, ids, x, y, theta, v, w, stopped, alive, frozen)
            return True

    def _write_snapshot(self, t, seq, ids, x, y, theta, v, w, stopped, alive, frozen) -> None:
        def col(a) -> list:
            return a.tolist() if isinstance(a, np.ndarray) else list(a)

        self._put(TOPIC_SNAPSHOT, t, json.dumps(
            {"t": float(t), "seq": int(seq), "id": col(ids), "x": col(x), "y": col(y), "theta": col(theta),
             "v": col(v), "w": col(w), "stopped": col(stopped), "alive": col(alive), "frozen": col(frozen)},
            separators=(",", ":"), allow_nan=False), int(seq))

    def ref(self, r: Ref) -> bool:
        with self._lock:
            self._check_open()
            if not self._keep(self._ref_grid, r.t):
                return False
            self._put(TOPIC_REF, r.t, f'{{"t":{r.t!r},"seq":{r.seq},"x":{r.x!r},"y":{r.y!r},"theta":{r.theta!r},'
                                      f'"v":{r.v!r},"w":{r.w!r}}}', r.seq)
            return True

    def cmd(self, robot: int, c: Cmd) -> bool:
        with self._lock:
            self._check_open()
            g = self._cmd_grid.get(robot)
            if g is None:
                g = self._cmd_grid[robot] = _Grid(self._grid_period, self.scenario.dt)
            if not self._keep(g, c.t):
                return False
            self._put(TOPIC_CMD, c.t, f'{{"t":{c.t!r},"seq":{c.seq},"id":{robot},"v":{c.v!r},"w":{c.w!r}}}', c.seq)
            return True

    def status(self, robot: int, s: Status) -> bool:
        with self._lock:
            self._check_open()
            g = self._status_grid.get(robot)
            if g is None:
                g = self._status_grid[robot] = _Grid(self.status_period, self.scenario.dt)
            if not self._keep(g, s.t):
                return False
            self._put(TOPIC_STATUS, s.t, f'{{"t":{s.t!r},"id":{robot},"ex":{s.ex!r},"ey":{s.ey!r},'
                                         f'"etheta":{s.etheta!r},"frozen":{_jbool(s.frozen)},'
                                         f'"neighbours":{s.neighbours},"stale":{s.stale},"bad":{s.bad}}}')
            return True

    def event(self, ev: Event) -> None:
        with self._lock:
            self._check_open()
            self._put(TOPIC_EVENTS, ev.t, json.dumps(ev.to_dict(), separators=(",", ":"), allow_nan=False))

    def fault(self, t: float, seq: int, event: str, robots, detail: str) -> None:
        """One fault event (/faults): the world/events message's fields (never decimated)."""
        with self._lock:
            self._check_open()
            self._put(TOPIC_FAULTS, t, json.dumps({"t": float(t), "seq": int(seq), "event": event,
                                                   "robots": [int(i) for i in robots], "detail": detail},
                                                  separators=(",", ":"), allow_nan=False), int(seq))

    def close(self, metrics: dict | None = None) -> None:
        """Write the held last snapshot and the metrics (the exact dict; None: no metrics), finish the file."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            try:
                if self._held is not None:
                    self._write_snapshot(*self._held)
                    self._held = None
                if metrics is not None:
                    try:
                        text = json.dumps(metrics, allow_nan=False)
                    except (TypeError, ValueError) as e:
                        raise RecordError(f"{self.path}: the metrics cannot be written as JSON: {e}") from None
                    self._put(TOPIC_METRICS, self.last_t, text)
            finally:
                self._w.finish()
                self._file.close()

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --------------------------------------------------------------------------- live: from the bus


class BusRecorder:
    """Records a live run from the bus: snapshots, leader reference, commands, statuses and fault events
    (world/events) of `fleet`.

    Bus callbacks (on the bus's thread) only append (topic, key, payload) to a deque; a worker thread
    decodes each payload with swarm.proto.protocol.decode (a bad one is dropped, counted in `bad` and written
    as a bad_message event; nothing raises into the bus), merges each robot's newest status freeze flag
    into the snapshots, derives the events (EventDeriver) and writes through the Recorder. Nothing is
    dropped: when MAX_PENDING messages wait, a callback waits for room. threaded=False: no worker; the
    owner calls drain() (deterministic tests, benches).
    """

    def __init__(self, bus, fleet: str, recorder: Recorder, max_pending: int = MAX_PENDING, threaded: bool = True,
                 commands_from_snapshots: bool = False):
        self.rec = recorder
        # Lock-step: the world applies exactly cmd_k over [t_k, t_k+1], so snapshot k+1 carries every
        # robot's cmd_k (v, w): one message a tick instead of N (a held command after a miss shows as
        # held; cmd_misses counts it). Real time keeps the robots' own command messages.
        self.commands_from_snapshots = commands_from_snapshots
        self._prev_tick: tuple[int, float] | None = None
        self.fleet = keys.check_fleet(fleet)
        scn = recorder.scenario
        self.n = scn.n
        self.events = EventDeriver(scn)
        self.bad = 0
        self.errors = 0  # unexpected failures while writing (logged; the recording goes on)
        self.received = 0
        self.snapshots = 0  # snapshots received (valid ones)
        self.first_seq: int | None = None  # seq of the first one
        self.snapshots_missed = 0  # gaps in their seq (best-effort messages lost on the way)
        self.last_snapshot_t = -math.inf  # simulated time of the newest snapshot processed
        self._last_seq: int | None = None
        # the world's snapshots pass a window as every receiver's messages do (lock-step: t is seq x dt): a forged
        # seq 10^6 is refused, not recorded, and never counted as a million snapshots lost on the way
        self._w_snap = window.new(*window.spans(scn.dt, WATCHDOG_S), dt=scn.dt if commands_from_snapshots else 0.0)
        self._frozen = [False] * self.n
        self._ids: dict[str, int | None] = {}
        self._pending: collections.deque = collections.deque()
        self._max = max_pending
        self._pending_bytes = 0  # the payload bytes in _pending (under _bytes_lock)
        self._bytes_lock = threading.Lock()
        self.snapshot_max = 256 + SNAPSHOT_ROW_BYTES * self.n  # bytes: a larger one is refused unread
        self._closing = threading.Event()
        self._open = True
        self._worker: threading.Thread | None = None
        if threaded:  # started before subscribing: a callback may come at once
            self._worker = threading.Thread(target=self._run, name="swarm-recorder", daemon=True)
            self._worker.start()
        # topic -> the bus callback (fn(key, payload)); public for benches that time it alone
        self.faults = 0  # fault events recorded
        self.callbacks = {topic: self._on(topic) for topic in (TOPIC_SNAPSHOT, TOPIC_REF, TOPIC_CMD, TOPIC_STATUS,
                                                               TOPIC_FAULTS)}
        cmds = [] if commands_from_snapshots else [bus.subscribe(keys.robot_any(fleet, "cmd"), self.callbacks[TOPIC_CMD])]
        self._handles = [
            bus.subscribe(keys.world_snapshot(fleet), self.callbacks[TOPIC_SNAPSHOT]),
            bus.subscribe(keys.leader_ref(fleet), self.callbacks[TOPIC_REF]),
            *cmds,
            bus.subscribe(keys.robot_any(fleet, "status"), self.callbacks[TOPIC_STATUS]),
            bus.subscribe(keys.world_events(fleet), self.callbacks[TOPIC_FAULTS]),
        ]

    def _on(self, topic: str):
        pending, limit, worker, lock = self._pending, self._max, self._worker, self._bytes_lock
        cap = self.snapshot_max if topic == TOPIC_SNAPSHOT else None

        def callback(key: str, payload: bytes) -> None:
            if not self._open:
                return
            size = len(payload)
            if cap is not None and size > cap:  # no snapshot of this run: counted by the worker, never decoded
                pending.append((_OVERSIZED, key, str(size).encode()))
                return
            with lock:
                self._pending_bytes += size
            pending.append((topic, key, payload))
            while (len(pending) > limit or self._pending_bytes > MAX_PENDING_BYTES) and worker is not None and \
                    worker.is_alive():
                time.sleep(0.001)  # back-pressure instead of a drop

        return callback

    def _next(self) -> tuple[str, str, bytes]:
        topic, key, payload = self._pending.popleft()
        if topic != _OVERSIZED:
            with self._bytes_lock:
                self._pending_bytes -= len(payload)
        return topic, key, payload

    def drain(self) -> int:
        """Process every message received so far on the caller's thread; returns how many."""
        done = 0
        pending = self._pending
        while pending:
            self.process(*self._next())
            done += 1
        return done

    # -- the worker

    def _run(self) -> None:
        while True:
            closing = self._closing.is_set()
            self.drain()
            if closing:
                return
            try:
                self.rec.flush_if_due()
            except Exception:  # a full disk, say: the next message's write reports it; keep draining
                self.errors += 1
                if self.errors <= 3:
                    log.exception("recorder: failed to flush the recording")
            self._closing.wait(POLL_S)

    def process(self, topic: str, key: str, payload: bytes) -> None:
        """Decode and record one received message (the worker calls this; tests and benches may too)."""
        self.received += 1
        try:
            if topic == _OVERSIZED:
                raise ProtocolError(f"a snapshot of {int(payload)} bytes: more than {self.n} robots' can be "
                                    f"({self.snapshot_max} bytes at most)")
            if topic == TOPIC_SNAPSHOT:
                self._snapshot(key, payload)
            elif topic == TOPIC_REF:
                self.rec.ref(protocol.decode(payload, "ref"))
            elif topic == TOPIC_FAULTS:
                self._fault(protocol.decode(payload, "event"))
            else:
                robot = self._robot(key)
                if topic == TOPIC_CMD:
                    self.rec.cmd(robot, protocol.decode(payload, "cmd"))
                else:
                    self._status(robot, protocol.decode(payload, "status"))
        except ProtocolError as e:
            self._bad(key, str(e))
        except Exception:  # a bug must not stop the recording (nor reach the bus's thread)
            if self.rec.closed:
                return
            self.errors += 1
            if self.errors <= 3:
                log.exception("recorder: failed to record a message on %s", key)

    def _robot(self, key: str) -> int:
        robot = self._ids.get(key, -1)
        if robot == -1:
            k = keys.parse(key)
            robot = self._ids[key] = k.id if k is not None and k.id is not None and k.id < self.n else None
        if robot is None:
            raise ProtocolError(f"key {key!r} does not name a robot of this scenario (0..{self.n - 1})")
        return robot

    def _bad(self, key: str, reason: str) -> None:
        self.bad += 1
        if self.bad <= MAX_BAD_EVENTS:
            k = keys.parse(key)
            more = "; later ones are counted, not written" if self.bad == MAX_BAD_EVENTS else ""
            self.rec.event(Event(self.rec.last_t, "bad_message", robot=k.id if k is not None else None,
                                 detail=f"{key}: {reason}{more}"))

    def _fault(self, ev: protocol.Event) -> None:
        if any(i >= self.n for i in ev.robots):
            raise ProtocolError(f"event {ev.event} names robot {max(ev.robots)}; the scenario has {self.n} "
                                f"(0..{self.n - 1})")
        self.rec.fault(ev.t, ev.seq, ev.event, ev.robots, ev.detail)
        self.faults += 1

    def _status(self, robot: int, s: Status) -> None:
        self._frozen[robot] = s.frozen
        ev = self.events.frozen(s.t, robot, s.frozen)
        if ev is not None:
            self.rec.event(ev)
        self.rec.status(robot, s)

    def _snapshot(self, key: str, payload: bytes) -> None:
        s: Snapshot = protocol.decode(payload, "snapshot")
        verdict = self._w_snap.check(s.t, s.seq)
        if verdict in (window.STALE, window.DUPLICATE):
            return  # best effort: an older one that came late is not recorded again
        if verdict != window.OK:
            raise ProtocolError(f"snapshot t = {s.t:g} s, seq {s.seq}: {verdict} (beyond the window of the world's "
                                "snapshots)")
        self.snapshots += 1
        self.last_snapshot_t = max(self.last_snapshot_t, s.t)
        if self._last_seq is None:
            self.first_seq = s.seq
        elif s.seq > self._last_seq + 1:
            self.snapshots_missed += s.seq - self._last_seq - 1
        self._last_seq = s.seq if self._last_seq is None else max(self._last_seq, s.seq)
        rows = s.robots
        n = self.n
        ids = [r.id for r in rows]
        if len(rows) == n and ids == list(range(n)):
            x = [r.x for r in rows]
            y = [r.y for r in rows]
            theta = [r.theta for r in rows]
            v = [r.v for r in rows]
            w = [r.w for r in rows]
            stopped = [r.stopped for r in rows]
            alive = [r.alive for r in rows]
            frozen = list(self._frozen)
        else:  # robots missing, reordered or unknown: keep the ids of this scenario
            known = [r for r in rows if r.id < n]
            if len(known) < len(rows):
                raise ProtocolError(f"snapshot names robot {max(ids)}; the scenario has {n} (0..{n - 1})")
            ids = [r.id for r in known]
            x, y, theta = [r.x for r in known], [r.y for r in known], [r.theta for r in known]
            v, w = [r.v for r in known], [r.w for r in known]
            stopped, alive = [r.stopped for r in known], [r.alive for r in known]
            frozen = [self._frozen[i] for i in ids]
        full_x, full_y = np.full(n, np.nan), np.full(n, np.nan)
        full_alive, full_stopped = np.zeros(n, bool), np.ones(n, bool)
        idx = np.asarray(ids, np.int64)
        full_x[idx], full_y[idx] = x, y
        full_alive[idx], full_stopped[idx] = alive, stopped
        for ev in self.events.snapshot(s.t, s.seq, full_x, full_y, full_alive, full_stopped):
            self.rec.event(ev)
        self.rec.snapshot(s.t, s.seq, ids, x, y, theta, v, w, stopped, alive, frozen)
        if self.commands_from_snapshots:
            prev, self._prev_tick = self._prev_tick, (s.seq, s.t)
            if prev is not None and s.seq == prev[0] + 1:
                for j, i in enumerate(ids):
                    if alive[j] and not stopped[j]:
                        self.rec.cmd(i, Cmd(t=prev[1], seq=prev[0], v=v[j], w=w[j]))

    # -- the end

    def wait_for(self, t: float | None, timeout_s: float) -> bool:
        """Wait at most timeout_s until the snapshot at simulated time t has been processed and nothing
        is pending (t None: only the latter). For the owner at the end of a run: the world's last
        messages may still be on their way when its process exits. True if it came."""
        end = time.monotonic() + timeout_s
        while True:
            if (t is None or self.last_snapshot_t >= t - 1e-6) and not self._pending:
                return True
            if time.monotonic() >= end:
                return False
            time.sleep(POLL_S / 2)

    @property
    def pending(self) -> int:
        return len(self._pending)

    def close(self, metrics: dict | None = None, timeout_s: float = 60.0) -> None:
        """Unsubscribe, write everything received, then the metrics, and finish the file."""
        for h in self._handles[::-1]:
            try:
                h.close()
            except Exception:  # the session may already be gone: nothing left to release
                pass
        self._handles.clear()
        self._closing.set()
        if self._worker is not None:
            self._worker.join(timeout_s)
        self._open = False
        if self._worker is not None and self._worker.is_alive():
            log.warning("recorder: %d messages still pending after %g s; finishing without them",
                        len(self._pending), timeout_s)
        else:  # what arrived after the worker's last drain (or everything, without a worker)
            self.drain()
        if self.bad > MAX_BAD_EVENTS:
            self.rec.event(Event(self.rec.last_t, "bad_message",
                                 detail=f"{self.bad} bad messages in all ({self.bad - MAX_BAD_EVENTS} not written)"))
        self.rec.close(metrics)


# --------------------------------------------------------------------------- `swarm sim`


def record_simulation(path, scenario: Scenario, result, record_hz: float | None = DEFAULT_RECORD_HZ) -> Path:
    """Write the recording of an in-process run: the same channels a live run has.

    result: a swarm.core.sim.Result, or a Simulation (run to the end here if it has not run). Its samples
    must be at least as dense as record_hz asks: build it with Simulation(scn,
    record_period=record_period(record_hz, scn.dt)) (denser samples are decimated here).
    Per sample: a snapshot (v, w: the command computed at the sample; stopped false, alive true),
    the leader reference, every robot's command; statuses every STATUS_PERIOD_S (errors against the
    live reference as the agents report them, neighbours: robots closer than the cell side). Events
    come from the samples (freeze changes, collisions between consecutive samples); the metrics count
    every step, so with a coarse record_hz they may count collisions that no sample shows.
    Under faults: /faults holds the schedule's events (swarm.core.faults.timeline) up to the last sample,
    each before the first sample at or after its time (seq: its tick, as the world tells it), and a
    snapshot's alive is false for a robot the schedule has dead (killed, not yet restarted).
    """
    from swarm.core.sim import Result, Simulation

    if isinstance(result, Simulation):
        result = result.run()
    if not isinstance(result, Result):
        raise TypeError(f"record_simulation needs a swarm.core.sim.Result or Simulation, got {type(result).__name__}")
    scn, rec = scenario, result.recording
    dt = scn.dt
    every = record_every(record_hz, dt)
    steps = np.rint(rec.t / dt).astype(np.int64)
    have = int(np.min(np.diff(steps[:-1]))) if len(steps) > 2 else every
    if len(steps) > 2 and (every % have or np.any(steps[:-1] % have)):
        raise RecordError(f"{path}: the simulation sampled every {have} steps; record_hz {record_hz} needs every "
                          f"{every}: build it with Simulation(scn, record_period=record_period({record_hz}, {dt}))")
    rows = np.flatnonzero((steps % every == 0) | (np.arange(len(steps)) == len(steps) - 1))
    table = scn.leader.table()
    deriver = EventDeriver(scn)
    sense = scn.cell_side
    ids = list(range(scn.n))
    not_stopped, alive = [False] * scn.n, [True] * scn.n
    all_alive, none_stopped = np.ones(scn.n, bool), np.zeros(scn.n, bool)
    timeline = []
    if scn.faults:
        from swarm.core import faults as schedule
        from swarm.core.faulttable import first_tick

        timeline = schedule.timeline(scn.faults, scn.n)
        marks = FaultMarks(scn.n)
    with Recorder(path, scn, record_hz, source="sim", status_period=max(STATUS_PERIOD_S, every * dt),
                  presampled=True) as out:
        for s in rows.tolist():
            t, k = float(rec.t[s]), int(steps[s])
            q, cmd, err, frozen = rec.q[s], rec.cmd[s], rec.err[s], rec.frozen[s]
            if not (np.isfinite(q).all() and np.isfinite(cmd).all()):
                raise RecordError(f"{path}: sample at t = {t:g} s is not finite")
            if timeline and timeline[0][0] <= t + TIME_EPS:
                while timeline and timeline[0][0] <= t + TIME_EPS:
                    te, name, robots, detail = timeline.pop(0)
                    out.fault(te, first_tick(te, dt), name, robots, detail)
                    marks.apply(te, name, robots)
                all_alive = ~marks.killed
                alive = all_alive.tolist()
            for ev in deriver.snapshot(t, None, q[:, 0], q[:, 1], all_alive, none_stopped):  # samples: gaps are normal
                out.event(ev)
            fl = frozen.tolist()
            for i, f in enumerate(fl):
                change = deriver.frozen(t, i, f)
                if change is not None:
                    out.event(change)
            out.snapshot(t, k, ids, q[:, 0], q[:, 1], q[:, 2], cmd[:, 0], cmd[:, 1], not_stopped, alive, fl)
            _x, _y, _th, vl, wl = kinematics.leader_state(table, t)
            lx, ly, lth = map(float, rec.leader[s])
            out.ref(Ref(t=t, seq=k, x=lx, y=ly, theta=lth, v=float(vl), w=float(wl)))
            vs, ws = cmd[:, 0].tolist(), cmd[:, 1].tolist()
            for i in ids:
                out.cmd(i, Cmd(t=t, seq=k, v=vs[i], w=ws[i]))
            pi, pj, _ = pairs_within(q[:, 0], q[:, 1], sense)
            neighbours = np.bincount(np.concatenate([pi, pj]), minlength=scn.n).tolist()
            ex, ey, eth = err[:, 0].tolist(), err[:, 1].tolist(), err[:, 2].tolist()
            for i in ids:
                out.status(i, Status(t=t, ex=ex[i], ey=ey[i], etheta=eth[i], frozen=fl[i],
                                     neighbours=neighbours[i], stale=0, bad=0))
        out.close(result.metrics)
    return Path(path)

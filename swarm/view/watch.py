"""Feeding a Viewer: from a live swarm over the bus (SwarmWatcher), or from the in-process simulator.

    watcher = SwarmWatcher(bus, fleet, viewer)       # scene: a SceneInfo, or None to ask the world
    watcher.start()                                 # subscribes; a draw thread paced at <= max_hz
    ...
    watcher.close()

An observer must never slow the swarm: the bus callbacks only store the newest bytes (the
snapshot in one slot, each robot's status in a dict) and wake the draw thread; decoding,
validation and drawing happen on the draw thread. A draw thread that falls behind skips frames:
it always takes the newest snapshot and drops the ones in between (counted in `skipped`). A bad
message is dropped and counted (`bad`), never raised.

Robot states: the world's snapshot says alive and stopped; each robot's status says frozen; a
robot whose newest status is older than `stale_after_s` wall seconds is stale (swarm.view.viz.state_codes).
Faults: the world's fault events (world/events: kill, restart, hang, resume, partition, partition_end)
say which robots are dead, hung or cut off (swarm.view.faultmarks; a viewer given the scenario starts
from its fault schedule, so one that joins late knows what happened before), and a robot whose fresh
status counts stale neighbour states gets the stale-data ring. Events are kept in order (every one
matters, not only the newest) and applied on the draw thread; one that names no robot of the run is
dropped and counted.
The overlay's counts (alive, converged, frozen, the smallest distance so far) come from the world's
progress messages (world/progress, about 4 a second), stored and decoded like the rest; until the first
one comes the viewer counts what the frame shows.
Without a scenario, the scene (offsets, radii, obstacles) comes from the world's queryables and the
leader's pose from its reference stream, advanced exactly along its arc to the snapshot's time.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import replace
from typing import Callable, cast

import numpy as np

from swarm.proto import keys, protocol
from swarm.core import kinematics
from swarm.proto.protocol import ProtocolError
from swarm.view.faultmarks import FaultMarks
from swarm.view.viz import DEAD, HUNG, STALE_AFTER_S, SceneInfo, Stats, Viewer, state_codes

log = logging.getLogger("swarm.viz")

MAX_HZ = 30.0
REFRESH_S = 0.5  # wall seconds between redraws when no snapshot comes (statuses going stale)
SCENE_RETRY_S = 5.0  # wall seconds between attempts to fetch the scene from the world
QUERY_TIMEOUT_S = 1.0
MAX_EVENTS = 10_000  # fault events waiting for the draw thread; beyond this they are dropped and counted


class SwarmWatcher:
    """Subscribes to a fleet's snapshot, statuses and leader reference and draws them in `viewer`."""

    def __init__(self, bus, fleet: str, viewer: Viewer, scene: SceneInfo | None = None, max_hz: float = MAX_HZ,
                 stale_after_s: float = STALE_AFTER_S, wall: Callable[[], float] = time.monotonic):
        if not max_hz > 0:
            raise ValueError(f"max_hz must be > 0, got {max_hz!r}")
        self.bus, self.fleet, self.viewer = bus, keys.check_fleet(fleet), viewer
        self.scene = scene  # None: fetched from the world on the first snapshot
        self.period = 1.0 / max_hz
        self.stale_after_s = stale_after_s
        self.wall = wall
        self.bad = protocol.BadMessages(log)
        self.received = 0  # snapshots that arrived
        self.taken = 0  # snapshots the draw thread took (the others were skipped)
        self.drawn = 0  # frames drawn
        self.error: Exception | None = None  # what stopped the draw thread, if anything
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._snap: bytes | None = None
        self._statuses: dict[str, tuple[bytes, float]] = {}
        self._ref: bytes | None = None
        self._progress: bytes | None = None
        self._events: list[bytes] = []  # world/events payloads, in order, until the draw thread takes them
        self.events = 0  # fault events applied
        self.events_dropped = 0  # fault events beyond MAX_EVENTS waiting (a stuck draw thread)
        self._handles: list = []
        self._thread: threading.Thread | None = None
        # draw-thread state
        self._frozen: dict[int, bool] = {}
        self._stale: dict[int, int] = {}  # robot -> stale neighbour states in its newest status
        self._status_at: dict[int, float] = {}
        self._marks: FaultMarks | None = None  # per robot: dead, hung, cut off (from the fault events)
        self._held_events: list[protocol.Event] = []  # decoded, waiting for a snapshot to say how many robots
        self._cut: np.ndarray | None = None  # the rings of the last frame drawn
        self._stale_rings: np.ndarray | None = None
        self._last: protocol.Snapshot | None = None
        self._last_ref: protocol.Ref | None = None
        self._stats: Stats | None = None  # from the newest progress message
        self._estop: str | None = None  # the emergency stop's reason while engaged (world/events); kept across runs:
        # the robots keep an engaged stop latched until its release, whatever run comes
        self._estop_drawn: str | None = None
        self._codes: np.ndarray | None = None
        self._started = wall()
        self._scene_n = -1
        self._scene_tried = -math.inf

    @property
    def skipped(self) -> int:
        return self.received - self.taken

    # ------------------------------------------------------------------ bus callbacks: store only

    def _on_snapshot(self, key: str, payload: bytes) -> None:
        with self._lock:
            self._snap = payload
            self.received += 1
        self._wake.set()

    def _on_status(self, key: str, payload: bytes) -> None:
        at = self.wall()
        with self._lock:
            self._statuses[key] = (payload, at)

    def _on_ref(self, key: str, payload: bytes) -> None:
        with self._lock:
            self._ref = payload

    def _on_progress(self, key: str, payload: bytes) -> None:
        with self._lock:
            self._progress = payload

    def _on_event(self, key: str, payload: bytes) -> None:
        with self._lock:
            if len(self._events) >= MAX_EVENTS:
                self.events_dropped += 1
                return
            self._events.append(payload)
        self._wake.set()

    # ------------------------------------------------------------------ life cycle

    def start(self, draw_thread: bool = True) -> None:
        """Subscribe, and start the draw thread (without it, a test calls step() itself)."""
        f = self.fleet
        self._handles.append(self.bus.subscribe(keys.world_snapshot(f), self._on_snapshot))
        self._handles.append(self.bus.subscribe(keys.robot_any(f, "status"), self._on_status))
        self._handles.append(self.bus.subscribe(keys.leader_ref(f), self._on_ref))
        self._handles.append(self.bus.subscribe(keys.world_progress(f), self._on_progress))
        self._handles.append(self.bus.subscribe(keys.world_events(f), self._on_event))
        if draw_thread:
            self._thread = threading.Thread(target=self._run, name="viz-draw", daemon=True)
            self._thread.start()

    def close(self, timeout_s: float = 5.0) -> None:
        for h in self._handles[::-1]:
            h.close()
        self._handles.clear()
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout_s)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # ------------------------------------------------------------------ the draw thread

    def _run(self) -> None:
        try:
            next_frame = 0.0
            while not self._stop.is_set():
                self._wake.wait(REFRESH_S)
                self._wake.clear()
                delay = next_frame - self.wall()
                if delay > 0 and self._stop.wait(delay):  # pacing: at most max_hz frames a second
                    break
                if self._stop.is_set():
                    break
                if self.step():
                    next_frame = self.wall() + self.period
        except Exception as e:  # the server went away, most likely: say so and stop drawing
            self.error = e
            log.error("viewer stopped: %s", e)

    def step(self) -> bool:
        """Take the newest data and draw one frame if there is something new; True if it drew."""
        with self._lock:
            payload, self._snap = self._snap, None
            statuses, self._statuses = self._statuses, {}
            ref = self._ref
            progress, self._progress = self._progress, None
            events, self._events = self._events, []
            if payload is not None:
                self.taken += 1
        self._take_statuses(statuses)
        if progress is not None:
            self._take_progress(progress)
        self._take_events(events)
        fresh = False
        if payload is not None:
            try:
                decoded = protocol.decode(payload, "snapshot")
            except ProtocolError as e:
                self.bad.reject(keys.world_snapshot(self.fleet), e)
            else:
                if self._last is not None and decoded.seq < self._last.seq:  # a new run: new scene, new trails
                    self._scene_n = -1
                    self._scene_tried = -math.inf
                    self._stats = None
                    self._marks = None
                self._last = decoded
                fresh = True
        snap = self._last
        if snap is None:
            return False
        ids = np.array([r.id for r in snap.robots], np.int64)
        marks = self._fault_marks(ids, snap.t)
        now = self.wall()
        id_list = ids.tolist()
        age = np.array([now - self._status_at.get(i, self._started) for i in id_list])
        codes = state_codes(np.array([r.alive for r in snap.robots], bool),
                            np.array([r.stopped for r in snap.robots], bool),
                            np.array([self._frozen.get(i, False) for i in id_list], bool), age,
                            self.stale_after_s, hung=marks.hung[ids], killed=marks.killed[ids])
        cut = marks.cut[ids]
        # a robot's stale count says something only while its status is fresh, and of a robot that computes
        stale = (np.array([self._stale.get(i, 0) > 0 for i in id_list], bool) & (age <= self.stale_after_s)
                 & (codes != DEAD) & (codes != HUNG))
        # a frame drawn (self.drawn) has set _codes, _cut and _stale_rings
        if (not fresh and self.drawn and np.array_equal(codes, cast(np.ndarray, self._codes))
                and np.array_equal(cut, cast(np.ndarray, self._cut))
                and np.array_equal(stale, cast(np.ndarray, self._stale_rings)) and self._estop == self._estop_drawn):
            refresh = getattr(self.viewer, "refresh_overlay", None)
            if refresh is not None:  # the overlay's last lines, held back by its pacing
                refresh()
            return False  # nothing new to show
        self._ensure_scene(len(ids))
        q = np.array([(r.x, r.y, r.theta) for r in snap.robots], float).reshape(-1, 3)
        set_marks = getattr(self.viewer, "set_marks", None)
        if set_marks is not None:
            set_marks(cut=cut, stale_data=stale)
        stats = self._stats if self._estop is None else replace(self._stats or Stats(), estop=self._estop)
        self.viewer.draw(snap.t, q, codes, self._leader(snap.t, ref), stats=stats)
        self._codes, self._cut, self._stale_rings, self._estop_drawn = codes, cut, stale, self._estop
        self.drawn += 1
        return True

    def _take_events(self, payloads: list[bytes]) -> None:
        """Decode the fault events that came (a bad one is dropped and counted); they wait for a snapshot
        (which says how many robots the run has) in _held_events."""
        for payload in payloads:
            try:
                self._held_events.append(protocol.decode(payload, "event"))
            except ProtocolError as e:
                self.bad.reject(keys.world_events(self.fleet), e)
        if len(self._held_events) > MAX_EVENTS:  # no snapshot for ages, and a flood of events: keep the newest
            self.events_dropped += len(self._held_events) - MAX_EVENTS
            del self._held_events[:-MAX_EVENTS]

    def _fault_marks(self, ids: np.ndarray, t: float) -> FaultMarks:
        """The run's fault marks, sized to the snapshot's robots (ids 0..n-1), with every event so far
        applied. A new one (first snapshot, a new run, another number of robots) starts from the scene's
        fault schedule up to t, when the scene has one: a viewer that joins late knows what happened."""
        n = int(ids.max()) + 1 if ids.size else 0
        m = self._marks
        if m is None or m.n != n:
            timeline = self.scene.timeline if self.scene is not None else ()
            m = self._marks = FaultMarks(n, timeline)
            m.advance(t)  # the same event from the bus later counts once
        for ev in self._held_events:
            if ev.event in ("estop", "estop_release"):  # the whole swarm's, not a robot's: the overlay says it
                self._estop = (ev.detail or "") if ev.event == "estop" else None
                continue
            ignored = m.ignored
            if m.apply(ev.t, ev.event, ev.robots):
                self.events += 1
            elif m.ignored > ignored:
                self.bad.reject(keys.world_events(self.fleet), ProtocolError(
                    f"event {ev.event} names robot {max(ev.robots)}; the run has robots 0..{n - 1}"))
        self._held_events.clear()
        return m

    def _take_statuses(self, statuses: dict[str, tuple[bytes, float]]) -> None:
        for key, (payload, at) in statuses.items():
            k = keys.parse(key)
            if k is None or k.kind != "status":
                self.bad.reject(key, ProtocolError("not a robot status key"))
                continue
            try:
                st = protocol.decode(payload, "status")
            except ProtocolError as e:
                self.bad.reject(key, e)
                continue
            i = cast(int, k.id)  # a status key names its robot
            self._frozen[i] = st.frozen
            self._stale[i] = st.stale
            self._status_at[i] = at

    def _take_progress(self, payload: bytes) -> None:
        try:
            p = protocol.decode(payload, "progress")
        except ProtocolError as e:
            self.bad.reject(keys.world_progress(self.fleet), e)
            return
        self._stats = Stats(alive=p.alive, converged=p.converged, frozen=p.frozen,
                            min_distance=p.min_distance if p.min_distance >= 0 else None)

    def _leader(self, t: float, ref_payload: bytes | None) -> tuple[float, float, float] | None:
        """The leader's pose at t: exact from the scene's segment table, else from its newest
        reference advanced along its arc (exact within a segment)."""
        if self.scene is not None and self.scene.leader_table is not None:
            return self.scene.leader_pose(t)
        if ref_payload is not None:
            try:
                self._last_ref = protocol.decode(ref_payload, "ref")
            except ProtocolError as e:
                self.bad.reject(keys.leader_ref(self.fleet), e)
        r = self._last_ref
        if r is None:
            return None
        dx, dy, dth = kinematics.arc_displacement(r.theta, r.v, r.w, t - r.t)
        return r.x + dx, r.y + dy, r.theta + dth

    # ------------------------------------------------------------------ the scene

    def _ensure_scene(self, n: int) -> None:
        """Give the viewer its scene: the one we were given, or the world's (asked again when the
        number of robots changes or a new run starts; at most every SCENE_RETRY_S on failure)."""
        if self._scene_n == n:
            return
        if self.scene is not None and (self.scene.offsets is None or len(self.scene.offsets) == n):
            self.viewer.set_scene(self.scene)
            self._scene_n = n
            return
        now = self.wall()
        if now - self._scene_tried < SCENE_RETRY_S:
            return
        self._scene_tried = now
        found = fetch_scene(self.bus, self.fleet, n, self.bad)
        if found is not None:
            self.scene = found
            self.viewer.set_scene(found)
            self._scene_n = n


def _query(bus, key: str, kind: str, key_id: int | None, bad: protocol.BadMessages):
    for rkey, payload in bus.query(key, timeout_s=QUERY_TIMEOUT_S):
        try:
            return protocol.decode(payload, kind, key_id)
        except ProtocolError as e:
            bad.reject(rkey, e)
    return None


def fetch_scene(bus, fleet: str, n: int, bad: protocol.BadMessages | None = None) -> SceneInfo | None:
    """The scene of a running swarm from the world's queryables: obstacles, and each robot's radii
    and offset from its configuration. None if the world does not answer for all of them."""
    bad = bad or protocol.BadMessages(log)
    obstacles = _query(bus, keys.world_obstacles(fleet), "obstacles", None, bad)
    if obstacles is None:
        log.info("viewer: the world does not answer on %s yet", keys.world_obstacles(fleet))
        return None
    configs = []
    for i in range(n):
        cfg = _query(bus, keys.world_config(fleet, i), "config", i, bad)
        if cfg is None:
            log.info("viewer: no configuration for robot %d yet", i)
            return None
        configs.append(cfg)
    obs = np.array([(o.x, o.y, o.r, o.R) for o in obstacles.obstacles], float).reshape(-1, 4)
    r = configs[0].r if configs else 0.3
    big_r = configs[0].R if configs else 1.2
    return SceneInfo(r=r, R=big_r, offsets=np.array([(c.dx, c.dy) for c in configs], float).reshape(-1, 2),
                     obstacles=obs)


# --------------------------------------------------------------------------- the in-process simulator


def play_simulation(sim, viewer: Viewer, speed: float = 1.0, should_stop: Callable[[], bool] | None = None,
                    progress: Callable | None = None, max_hz: float = MAX_HZ,
                    wait: Callable[[float], object] | None = None) -> bool:
    """Run `sim` (a swarm.core.sim.Simulation) to its end at `speed` simulated seconds per wall second
    (or as fast as it can, if slower), drawing its newest recorded sample at most max_hz times a
    second. Returns True if should_stop() ended it early. The overlay's counts are the simulator's
    (converged and frozen at the newest step, the smallest robot distance so far). Under faults the
    robots' marks come from the schedule (swarm.core.faults.timeline: dead, hung, cut off at the
    sample's time) and the simulator's own state (stopped by the watchdog, stale neighbour data:
    sim_fault_flags).

    The simulator advances in chunks that take about 50 ms each, so frames keep coming even when
    the simulation is slower than asked. `wait(seconds)` paces frames (default: an Event's wait)."""
    if not speed > 0:
        raise ValueError(f"speed must be > 0, got {speed!r}")
    wait = wait or threading.Event().wait
    dt = sim.scn.dt
    limit = max(1, int(round(0.05 / dt)))  # steps per chunk, adapted to take ~50 ms
    t0 = time.monotonic()
    period = 1.0 / max_hz
    n = sim.scn.n
    marks = None
    if sim.scn.faults:
        from swarm.core.faults import timeline

        marks = FaultMarks(n, timeline(sim.scn.faults, n))
    set_marks = getattr(viewer, "set_marks", None)
    while True:
        frame_start = time.monotonic()
        if should_stop is not None and should_stop():
            return True
        if not sim.done:
            want = min(sim.n_steps, int(math.floor(speed * (frame_start - t0) / dt + 1e-9))) + 1
            k_end = min(want, sim.next_k + limit)
            if k_end > sim.next_k:
                steps = k_end - sim.next_k
                sim.advance(k_end)
                spent = time.monotonic() - frame_start
                if spent > 0:
                    limit = max(1, min(int(steps * 0.05 / spent), 10 * limit))
        rec = sim.recording()
        p = sim.progress()
        if len(rec.t):
            t = float(rec.t[-1])
            alive = n
            if marks is None:
                codes = state_codes(np.ones(n, bool), np.zeros(n, bool), rec.frozen[-1], np.zeros(n))
                cut = stale = np.zeros(n, bool)
            else:
                marks.advance(t)
                stopped, stale = sim_fault_flags(sim)
                codes = state_codes(np.ones(n, bool), stopped, rec.frozen[-1], np.zeros(n), hung=marks.hung,
                                    killed=marks.killed)
                cut, stale = marks.cut, stale & (codes != DEAD) & (codes != HUNG)
                alive = n - int(marks.killed.sum())
            if set_marks is not None:
                set_marks(cut=cut, stale_data=stale)
            stats = Stats(alive=alive, converged=p.converged, frozen=p.frozen, min_distance=p.min_distance)
            leader = cast("tuple[float, float, float]", tuple(map(float, rec.leader[-1])))  # a row is (x, y, theta)
            viewer.draw(t, rec.q[-1], codes, leader, stats=stats)
        if progress is not None:
            progress(p)
        if sim.done:
            refresh = getattr(viewer, "refresh_overlay", None)
            if refresh is not None:  # the overlay shows the very end
                refresh()
            return False
        left = period - (time.monotonic() - frame_start)
        if left > 0:
            wait(left)


def sim_fault_flags(sim) -> tuple[np.ndarray, np.ndarray]:
    """(stopped, stale) (N,) bool of a swarm.core.sim.Simulation under faults, at its newest step: the
    world's watchdog stopped the robot; the robot's law takes a known neighbour whose newest delivered
    state is older than the step (what an agent's status counts as `stale`). Read from the fault
    kernel's state (swarm.core.faultsim.FaultState: tk, the tick of the newest state robot i has of
    robot j, and tx, ty, its position; bel, each robot's belief of its own pose), with the kernel's rule
    for which neighbours a law takes (known, not a static body, within the cell side of its belief).
    Both all false without faults."""
    from swarm.core import faultgen as fg

    n = sim.scn.n
    f = sim.faults
    if f is None or n == 0:
        return np.zeros(n, bool), np.zeros(n, bool)
    k = sim.next_k - 1
    stopped = np.asarray(f.stopped, bool).copy()
    static = stopped | (f.proc == fg.PROC_DEAD)
    known = (f.tk >= 0) & ~static[None, :]
    np.fill_diagonal(known, False)
    side = sim.sense
    near = (f.bel[:, 0:1] - f.tx) ** 2 + (f.bel[:, 1:2] - f.ty) ** 2 < side * side
    stale = (known & near & (f.tk < k)).any(axis=1) & (f.proc == fg.PROC_ALIVE)
    return stopped, stale

"""The swarm drawn in meshcat: one InstancedMesh per frame, whatever the number of robots.

    viewer = Viewer(server, SceneInfo.from_scenario(scn))    # a MeshcatServer, its client, or a meshcat Visualizer
    viewer.draw(t, q, codes, leader=(x, y, theta))           # q (N, 3) x, y, theta; codes (N,) TRACKING ...

The drawing knows nothing of zenoh, processes or where the poses come from: `swarm.view.watch` feeds it
from a live swarm, `swarm sim --viz` from the simulator, a replay from a recording.

Scene (z up, metres): a ground with a 2 m grid; obstacles (r solid, R translucent with its rim);
the robots, coloured by state with a dark arrow for the heading (optionally their R ring); the
formation as ghosts: the leader (translucent arrow) and every slot (translucent disc at leader +
offset: the law adds the offsets unrotated, docs/design.md); trails (one LineSegments, resent
once a second). A robot's body has radius r/2, so two bodies touch exactly when their centres are
r apart: a collision.

Faults: a robot's body shows its state (dead, hung, stopped by the watchdog, no recent status, frozen,
tracking: state_codes), and rings on the ground around it what it hears: a red ring when a partition
cuts it off from the world's group, a yellow one when its law used a neighbour's state that was not
current (stale neighbour data). set_marks() gives the rings of the next frame; where the flags come
from (world/events, a recording, the fault schedule) is swarm.view.faultmarks and the feeders'.

Overlay: a legend of every colour at the bottom of the view and, at the top, the scenario's name,
the simulated time, the robots alive, converged and frozen and the smallest robot-robot distance so
far; once a robot is dead, hung, cut off or uses stale data (or the run has scheduled faults), a third
line counts the robots dead, hung, stopped, cut off and using stale neighbour data. meshcat 0.3.2 has
no text command and no way to put HTML on its page, so the overlay is made of three.js objects that
are children of the camera (/Cameras/default/rotated/<object>/hud): they stay put on the screen
whatever the user's orbit and zoom. Text is meshcat's own "_text" texture (the
browser draws it on a canvas; swarm.view.meshcat_objects.label), one short line per object, redrawn
only when it changed and at most every HUD_PERIOD_S of wall time. The counts come with the frame
(`Stats`: from the world's progress messages, or the simulator); what a frame does not bring is
computed from it: alive and frozen from the state codes, converged from the slots and the leader,
the smallest distance from the poses (a running minimum over the frames drawn).

Per frame: one set_object (every robot in one InstancedMesh, with per-instance colour) and three
set_transform (the scene root, the formation, the leader), whatever N (and, while some robot has a
ring, one more set_object: every ring in one InstancedMesh); meshcat 0.3.2 has no batch
command and each command is a ZMQ round trip (docs/viewer.md). A static twin of the
robots' mesh stays in the scene so that three.js keeps the shader program when set_object
disposes the old material (without it the program is recompiled every frame). The camera cannot
be aimed through meshcat 0.3.2 (its orbit target stays at the origin), so the scene moves
instead: the root is translated to put the swarm's centre at the origin, and the camera is moved
back when the swarm grows or shrinks a lot.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from swarm.core.geometry import closest_pair
from swarm.view import meshcat_objects as mo
from swarm.view.meshcat_objects import poses_to_matrices
from swarm.core.metrics import CONVERGED_ANGLE_RAD, CONVERGED_POSITION_M

# Robot states (codes; state_codes gives their priority: dead > hung > stopped > stale > frozen > tracking).
TRACKING, FROZEN, STALE, STOPPED, DEAD, HUNG = 0, 1, 2, 3, 4, 5
STATE_NAMES = ("tracking", "frozen", "stale", "stopped", "dead", "hung")
# 0xRRGGBB per state: tracking green, frozen orange, stale (no recent status) grey, stopped purple,
# dead black, hung magenta.
STATE_COLORS = (0x2CA02C, 0xFF7F0E, 0x9E9E9E, 0x9467BD, 0x111111, 0xF032E6)
STALE_AFTER_S = 1.0  # wall seconds without a status before a robot shows as stale
# Rings on the ground around a robot (set_marks): cut off by a partition, using stale neighbour data.
CUT_COLOR = 0xE6194B  # red
STALE_DATA_COLOR = 0xFFE119  # yellow
MARK_INNER = 0.79  # inner radius of a ring / its outer radius
CUT_RING = 0.95  # outer radius of the cut-off ring / r (the body's radius is r / 2)
STALE_DATA_RING = 0.70  # outer radius of the stale-data ring / r (inside the cut-off ring)
MARK_Z = 0.012  # m: above the ground and the trails

GHOST_COLOR = 0x1E90FF
GROUND_COLOR = 0xF4F4F4
GRID_COLOR = 0xD2D2D2
OBSTACLE_COLOR = 0x5A5A5A
ZONE_COLOR = 0xFF2222
TRAIL_COLOR = 0x6A8CAF

ROOT = "/swarm"
CAMERA = "/Cameras/default/rotated/<object>"
BODY_HEIGHT = 0.12  # m
GROUND_HALF = 80.0  # m: the ground is redrawn around the swarm when it goes more than half of this away
TRAIL_PERIOD_S = 1.0  # wall seconds between trail updates
TRAIL_SAMPLE_S = 0.2  # simulated seconds between trail points
TRAIL_VERTICES = 40_000  # budget: each robot keeps at most this / N / 2 points, and at most 150
FOV_DEG = 75.0  # meshcat's default camera

# The overlay (see the module docstring), in the camera's frame: x right, y up, z toward the viewer [m].
HUD = CAMERA + "/hud"
HUD_DEPTH = 1.0  # m in front of the camera (beyond its near plane, 0.1 m); the view is 2 tan(fov / 2) tall there
HUD_PERIOD_S = 0.25  # wall seconds between overlay updates
HUD_FONT_PX = 26  # on the 256-pixel canvas: about 18 screen pixels in a 768-pixel-high window
LEGEND_FONT_PX = 22
HUD_CELL_W = 0.36  # m at HUD_DEPTH: one text cell of the top panel (3 columns)
HUD_ROW_H = 0.055  # m: between the top panel's lines
LEGEND_CELL_W = 0.30  # m: one legend entry (4 columns)
LEGEND_ROW_H = 0.06  # m: between the legend's rows
PANEL_COLOR = 0xFFFFFF
# A robot is converged within these of its slot and the leader's heading (as swarm.core.kernel and
# world.referee count it).
# (name, label, colour, opacity) of every legend entry, in reading order (4 a row: the robots' states,
# the hung and dead ones and the two rings, then the scene); the rings' swatches are rings
LEGEND = (
    ("tracking", "tracking", STATE_COLORS[TRACKING], 1.0),
    ("frozen", "frozen", STATE_COLORS[FROZEN], 1.0),
    ("stale", "no recent status", STATE_COLORS[STALE], 1.0),
    ("stopped", "stopped (watchdog)", STATE_COLORS[STOPPED], 1.0),
    ("hung", "hung", STATE_COLORS[HUNG], 1.0),
    ("dead", "dead", STATE_COLORS[DEAD], 1.0),
    ("cut", "cut off", CUT_COLOR, 1.0),
    ("stale_data", "stale neighbour data", STALE_DATA_COLOR, 1.0),
    ("leader", "leader and slots", GHOST_COLOR, 0.6),
    ("obstacle", "obstacle (r)", OBSTACLE_COLOR, 1.0),
    ("zone", "avoidance zone (R)", ZONE_COLOR, 0.35),
)
RING_SWATCHES = ("cut", "stale_data")
FAULT_CELLS = ("dead_hung", "stopped_cut", "stale_data")  # the overlay's third line


def rgb(hex_color: int) -> tuple[float, float, float]:
    return ((hex_color >> 16) & 255) / 255.0, ((hex_color >> 8) & 255) / 255.0, (hex_color & 255) / 255.0


PALETTE = np.array([rgb(c) for c in STATE_COLORS], np.float32)  # (6, 3) in [0, 1]


@dataclass(frozen=True)
class Stats:
    """The overlay's counts for a frame, where the caller knows them (None: the viewer works it out
    from the frame). min_distance [m]: the smallest robot-robot distance of the run so far."""

    alive: int | None = None
    converged: int | None = None
    frozen: int | None = None
    min_distance: float | None = None
    estop: str | None = None  # the emergency stop's reason while it is engaged ("" when it gave none)


def state_codes(alive: np.ndarray, stopped: np.ndarray, frozen: np.ndarray, status_age_s: np.ndarray,
                stale_after_s: float = STALE_AFTER_S, hung: np.ndarray | None = None,
                killed: np.ndarray | None = None) -> np.ndarray:
    """(N,) state codes from the flags: dead (killed, or not alive and not hung) > hung > stopped >
    stale (last status older than stale_after_s wall seconds) > frozen > tracking. All inputs (N,);
    ages in seconds; hung and killed (the fault events': swarm.view.faultmarks) may be None. A hung
    process past its zenoh lease loses its liveliness: it shows hung, not dead."""
    codes = np.full(len(alive), TRACKING, np.int8)
    codes[np.asarray(frozen, bool)] = FROZEN
    codes[np.asarray(status_age_s, float) > stale_after_s] = STALE
    codes[np.asarray(stopped, bool)] = STOPPED
    codes[~np.asarray(alive, bool)] = DEAD
    if hung is not None:
        codes[np.asarray(hung, bool)] = HUNG
    if killed is not None:
        codes[np.asarray(killed, bool)] = DEAD
    return codes


# --------------------------------------------------------------------------- what is static


@dataclass(frozen=True)
class SceneInfo:
    """What does not move: radii [m], formation offsets (N, 2) (None: no slots drawn), obstacles
    (M, 4) x, y, r, R, and the leader's segment table (swarm.core.kinematics; None: the leader's pose
    comes with each frame, or there is none)."""

    r: float = 0.3
    R: float = 1.2
    offsets: np.ndarray | None = None
    obstacles: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    leader_table: np.ndarray | None = None
    name: str = ""
    timeline: tuple = ()  # the fault schedule's events (swarm.core.faults.timeline): a late viewer starts from it

    def __post_init__(self) -> None:
        if not (0 < self.r < self.R and math.isfinite(self.R)):
            raise ValueError(f"radii must satisfy 0 < r < R, got r = {self.r}, R = {self.R}")
        obs = np.asarray(self.obstacles, float).reshape(-1, 4)
        object.__setattr__(self, "obstacles", obs)
        if self.offsets is not None:
            object.__setattr__(self, "offsets", np.asarray(self.offsets, float).reshape(-1, 2))

    @classmethod
    def from_scenario(cls, scn) -> "SceneInfo":
        timeline: tuple = ()
        if getattr(scn, "faults", None):
            from swarm.core.faults import timeline as fault_timeline

            timeline = tuple(fault_timeline(scn.faults, scn.n))
        return cls(r=float(scn.r), R=float(scn.R), offsets=np.array(scn.offsets, float),
                   obstacles=np.array(scn.obstacles, float), leader_table=scn.leader.table(), name=scn.name,
                   timeline=timeline)

    def leader_pose(self, t: float) -> tuple[float, float, float] | None:
        if self.leader_table is None:
            return None
        from swarm.core.kinematics import leader_state

        x, y, th, _v, _w = leader_state(self.leader_table, t)
        return x, y, th


def robot_shape(r: float, R: float, rings: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One robot, in its own frame (x forward): a cylinder of radius r/2, a dark arrow on top, and
    optionally its R ring on the ground. Vertex colours are greys that the instance colour tints."""
    body = 0.5 * r
    top_pos, top_idx = mo.disc(body, BODY_HEIGHT)
    side_pos, side_idx = mo.cylinder_side(body, BODY_HEIGHT)
    arr_pos, arr_idx = mo.arrow(1.25 * body, 1.1 * body, BODY_HEIGHT + 0.004)
    parts = [(top_pos, top_idx, 1.0), (side_pos, side_idx, 0.75), (arr_pos, arr_idx, 0.3)]
    if rings:
        ring_pos, ring_idx = mo.annulus(R - 0.03, R, 0.004)
        parts.append((ring_pos, ring_idx, 0.85))
    return mo.merge(parts)


# --------------------------------------------------------------------------- the viewer


class Viewer:
    """Draws frames of a swarm into meshcat (see the module docstring). Not thread-safe: one
    thread draws."""

    def __init__(self, target, scene=None, rings: bool = False, trails: bool = True, overlay: bool = True,
                 clock=time.monotonic):
        self.sink = mo.sink_of(target)
        self.rings, self.trails, self.overlay = rings, trails, overlay
        self.clock = clock  # wall time [s] for the overlay's pacing
        self._hud_sent: dict[str, str] = {}  # cell -> the text on screen
        self._hud_want: dict[str, str] = {}  # cell -> the newest text
        self._hud_at = -math.inf
        self._min_seen = math.inf  # m, running minimum of the frames drawn (when no Stats bring it)
        self.frames = 0
        self.costs: list[float] = []  # seconds of Python per draw(), the last 1000
        self._centre: np.ndarray | None = None
        self._cam_dist = 0.0
        self._cam_time = -math.inf
        self._trail: np.ndarray | None = None  # (L, N, 2) ring buffer of positions
        self._trail_k = 0
        self._trail_t = -math.inf
        self._trail_sent = -math.inf
        self._last_t = -math.inf
        self._formation_shown: bool | None = None
        self._next_cut: np.ndarray | None = None  # set_marks(): the rings of the next frame
        self._next_stale: np.ndarray | None = None
        self._marks_shown = False  # /swarm/marks is in the scene
        self._frame_marks: tuple[np.ndarray, np.ndarray | None] = (np.zeros(0, bool), None)  # the last frame's rings
        self._fault_row = False  # the overlay's third line is shown (sticky for a run)
        self._send({"type": "set_property", "path": "/Grid", "property": "visible", "value": False})
        self._send({"type": "set_property", "path": "/Axes", "property": "visible", "value": False})
        for prop, value in (("near", 0.1), ("far", 2000.0)):  # meshcat's 0.01..100 cannot see 60 m away
            self._send({"type": "set_property", "path": CAMERA, "property": prop, "value": value})
        self.set_scene(scene)

    def _send(self, data: dict) -> None:
        self.sink.send(mo.Command(data))

    def _set_object(self, path: str, obj: dict) -> None:
        self._send({"type": "set_object", "path": path, "object": obj})

    def _set_transform(self, path: str, matrix: list[float]) -> None:
        self._send({"type": "set_transform", "path": path, "matrix": matrix})

    def _delete(self, path: str) -> None:
        self._send({"type": "delete", "path": path})

    # ------------------------------------------------------------------ static parts

    def set_scene(self, scene=None) -> None:
        """(Re)draw what does not move; `scene` is a SceneInfo, a Scenario or None (robots only)."""
        if scene is not None and not isinstance(scene, SceneInfo):
            scene = SceneInfo.from_scenario(scene)
        self.scene = scene or SceneInfo()
        s = self.scene
        for part in ("obstacles", "formation", "ground", "trails", "robots", "keep"):
            self._delete(f"{ROOT}/{part}")
        self._delete(HUD)
        self._delete(f"{ROOT}/marks")
        self._marks_shown = False
        self._hud_sent, self._hud_want, self._hud_at, self._min_seen = {}, {}, -math.inf, math.inf
        self._fault_row = False
        self._hud_rows = 2  # lines of the top panel on screen
        if self.overlay:
            self._draw_overlay()
        self._trail = None
        self._formation_shown = None
        self._ground_at: np.ndarray | None = None
        if len(s.obstacles):
            self._draw_obstacles(s.obstacles)
        if s.offsets is not None and len(s.offsets):
            disc_pos, disc_idx = mo.disc(0.5 * s.r, 0.002)
            geo = mo.geometry(disc_pos, disc_idx)
            mat = mo.material(color=GHOST_COLOR, opacity=0.35, depth_write=False)
            q = np.c_[s.offsets, np.zeros(len(s.offsets))]
            self._set_object(f"{ROOT}/formation/slots", mo.instanced(geo, mat, "swarm_slots", poses_to_matrices(q), None))
        arrow_pos, arrow_idx = mo.arrow(0.6, 0.5, 0.003)
        ring_pos, ring_idx = mo.annulus(0.5 * s.r - 0.03, 0.5 * s.r, 0.003)
        pos, idx, _ = mo.merge([(arrow_pos, arrow_idx, 1.0), (ring_pos, ring_idx, 1.0)])
        ghost = mo.material(color=GHOST_COLOR, opacity=0.6, depth_write=False)
        self._set_object(f"{ROOT}/formation/leader", mo.mesh_object("Mesh", mo.geometry(pos, idx), ghost, "swarm_leader"))
        pos, idx, col = robot_shape(s.r, s.R, self.rings)
        self._robot_geometry = mo.geometry(pos, idx, col)
        self._robot_material = mo.material(vertex_colors=True)
        # The static twin: keeps the robots' shader program alive across set_object (see module doc).
        twin = mo.instanced(self._robot_geometry, mo.material(vertex_colors=True), "swarm_keep",
                          np.diag([0.0, 0.0, 0.0, 1.0]).astype(np.float32).reshape(1, 16), np.ones((1, 3)))
        self._set_object(f"{ROOT}/keep/robots", twin)
        # the rings (set_marks): one unit ring, scaled per instance; white vertex colours and the robots'
        # material settings, so that they share the robots' shader program (kept alive by the twin)
        ring_pos, ring_idx = mo.annulus(MARK_INNER, 1.0, 0.0)
        self._mark_geometry = mo.geometry(ring_pos, ring_idx, np.ones((len(ring_pos), 3)))
        self._mark_material = mo.material(vertex_colors=True)

    def _draw_obstacles(self, obs: np.ndarray) -> None:
        q = np.c_[obs[:, :2], np.zeros(len(obs))]
        side_pos, side_idx = mo.cylinder_side(1.0, 0.5)
        top_pos, top_idx = mo.disc(1.0, 0.5)
        pos, idx, col = mo.merge([(side_pos, side_idx, 0.7), (top_pos, top_idx, 1.0)])
        bodies = np.zeros((len(obs), 16), np.float32)
        bodies[:] = poses_to_matrices(q)
        bodies[:, 0] = bodies[:, 5] = obs[:, 2]  # scale x, y by r (no rotation)
        self._set_object(f"{ROOT}/obstacles/bodies", mo.instanced(
            mo.geometry(pos, idx, col), mo.material(color=OBSTACLE_COLOR, vertex_colors=True), "swarm_obstacles",
            bodies, None))
        zone_pos, zone_idx = mo.disc(1.0, 0.003, 48)
        zones = poses_to_matrices(q)
        zones[:, 0] = zones[:, 5] = obs[:, 3]
        self._set_object(f"{ROOT}/obstacles/zones", mo.instanced(
            mo.geometry(zone_pos, zone_idx), mo.material(color=ZONE_COLOR, opacity=0.18, depth_write=False),
            "swarm_zones", zones, None))
        a = np.linspace(0, 2 * np.pi, 49)
        rims = []
        for x, y, _r, big in obs:
            p = np.c_[x + big * np.cos(a), y + big * np.sin(a), np.full(49, 0.006)]
            rims.append(np.repeat(p, 2, axis=0)[1:-1])
        self._set_object(f"{ROOT}/obstacles/rims", mo.mesh_object(
            "LineSegments", mo.geometry(np.vstack(rims)), mo.material("LineBasicMaterial", ZONE_COLOR), "swarm_rims"))

    def _draw_ground(self, centre: np.ndarray) -> None:
        """A square ground of GROUND_HALF m around `centre`, with grid lines every 2 m, each cut in
        8 m pieces: headless Chromium's SwiftShader drops a line that crosses behind the camera."""
        half, step, piece = GROUND_HALF, 2.0, 8.0
        cx, cy = np.round(centre / piece) * piece
        ground = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float) * [half, half, 0]
        ground += [cx, cy, -0.02]
        self._set_object(f"{ROOT}/ground/plane", mo.mesh_object(
            "Mesh", mo.geometry(ground, np.array([0, 1, 2, 0, 2, 3])), mo.material(color=GROUND_COLOR), "swarm_ground"))
        ticks = np.arange(-half, half + step / 2, step)
        cuts = np.arange(-half, half, piece)
        a, b = np.meshgrid(ticks, cuts, indexing="ij")  # a: the line's offset, b: where the piece starts
        a, b = a.ravel(), b.ravel()
        along_y = np.stack([np.c_[a, b], np.c_[a, b + piece]], axis=1)  # (K, 2 ends, 2)
        along_x = along_y[:, :, ::-1]
        ends = np.vstack([along_y, along_x]).reshape(-1, 2) + [cx, cy]
        self._set_object(f"{ROOT}/ground/grid", mo.mesh_object(
            "LineSegments", mo.geometry(np.c_[ends, np.zeros(len(ends))]), mo.material("LineBasicMaterial", GRID_COLOR),
            "swarm_grid"))
        self._ground_at = np.array([cx, cy])

    # ------------------------------------------------------------------ frames

    def draw(self, t: float, q: np.ndarray, codes: np.ndarray, leader: tuple[float, float, float] | None = None,
             stats: Stats | None = None) -> None:
        """One frame at simulated time t [s]: q (N, 3) poses, codes (N,) states (TRACKING ...),
        leader (x, y, theta) or None (then the scene's leader table is used, if any); stats: the
        overlay's counts where the caller knows them."""
        started = time.perf_counter()
        q = np.asarray(q, float).reshape(-1, 3)
        codes = np.asarray(codes).reshape(-1)
        if len(codes) != len(q):
            raise ValueError(f"{len(q)} poses but {len(codes)} state codes")
        cut, stale = self._take_marks(len(q))
        if leader is None:
            leader = self.scene.leader_pose(t)
        if t < self._last_t:  # a new run (or a replay rewound): forget the trails, the minimum, the faults' line
            self._trail = None
            self._min_seen = math.inf
            self._hud_at = -math.inf
            self._fault_row = False
        self._last_t = t
        centre = self._frame_centre(q, leader)
        if self._ground_at is None or np.abs(centre - self._ground_at).max() > 0.5 * GROUND_HALF:
            self._draw_ground(centre)
        self._set_transform(ROOT, mo.translation(-centre[0], -centre[1]))
        self._frame_camera(q, leader, centre)
        colours = PALETTE[np.clip(codes, 0, len(PALETTE) - 1).astype(np.intp)]
        self._set_object(f"{ROOT}/robots", mo.instanced(self._robot_geometry, self._robot_material, "swarm_robots",
                                                      poses_to_matrices(q), colours))
        self._draw_marks(q, codes, cut, stale)
        show = leader is not None
        if show != self._formation_shown:
            self._send({"type": "set_property", "path": f"{ROOT}/formation", "property": "visible", "value": show})
            self._formation_shown = show
        if leader is not None:
            self._set_transform(f"{ROOT}/formation", mo.translation(leader[0], leader[1]))
            self._set_transform(f"{ROOT}/formation/leader", mo.translation(0.0, 0.0, 0.0, leader[2]))
        if self.trails:
            self._update_trails(t, q)
        if self.overlay:
            self._hud_want = self.overlay_texts(t, q, codes, leader, stats)
            if self.clock() - self._hud_at >= HUD_PERIOD_S:
                self.refresh_overlay()
        self.frames += 1
        self.costs.append(time.perf_counter() - started)
        if len(self.costs) > 1000:
            del self.costs[:500]

    def set_marks(self, cut: np.ndarray | None = None, stale_data: np.ndarray | None = None) -> None:
        """The rings of the next draw() only: cut (N,) bool, robots cut off from the world's group by a
        partition; stale_data (N,) bool, robots whose law used a neighbour's state that was not current
        (None: not known; the overlay then shows a dash). Rows like draw()'s q. A dead robot gets none."""
        self._next_cut = None if cut is None else np.asarray(cut, bool).reshape(-1)
        self._next_stale = None if stale_data is None else np.asarray(stale_data, bool).reshape(-1)

    def _take_marks(self, n: int) -> tuple[np.ndarray, np.ndarray | None]:
        cut, stale = self._next_cut, self._next_stale
        self._next_cut = self._next_stale = None
        for name, a in (("cut", cut), ("stale_data", stale)):
            if a is not None and len(a) != n:
                raise ValueError(f"{n} poses but {len(a)} {name} marks")
        return (np.zeros(n, bool) if cut is None else cut), stale

    def _draw_marks(self, q: np.ndarray, codes: np.ndarray, cut: np.ndarray, stale: np.ndarray | None) -> None:
        """One InstancedMesh of rings (a red one per robot cut off, a yellow one per robot on stale data),
        sent only while some robot has one; deleted once when none has."""
        live = (codes != DEAD) & np.isfinite(q).all(axis=1)  # (a robot missing from a replayed frame: NaN)
        cut = cut & live
        stale = None if stale is None else stale & live
        self._frame_marks = (cut, stale)
        rows = [(cut, CUT_RING, CUT_COLOR)] + ([] if stale is None else [(stale, STALE_DATA_RING, STALE_DATA_COLOR)])
        sel = [(np.flatnonzero(m), ring, colour) for m, ring, colour in rows if m.any()]
        if not sel:
            if self._marks_shown:
                self._delete(f"{ROOT}/marks")
                self._marks_shown = False
            return
        idx = np.concatenate([i for i, _, _ in sel])
        scale = np.concatenate([np.full(len(i), ring * self.scene.r) for i, ring, _ in sel])
        colours = np.vstack([np.tile(rgb(colour), (len(i), 1)) for i, _, colour in sel]).astype(np.float32)
        self._set_object(f"{ROOT}/marks", mo.instanced(self._mark_geometry, self._mark_material, "swarm_marks",
                                                     poses_to_matrices(q[idx], scale, MARK_Z), colours))
        self._marks_shown = True

    # ------------------------------------------------------------------ the overlay

    def _hud_layout(self) -> dict[str, tuple[float, float]]:
        """Centres (x, y) [m at HUD_DEPTH] of the top panel's cells (3 lines of 3, the third for faults):
        centred, so that they stay in view in any window at least 0.8 times as wide as it is high."""
        top = HUD_DEPTH * math.tan(math.radians(FOV_DEG / 2))
        rows = (top - 0.05, top - 0.05 - HUD_ROW_H, top - 0.05 - 2 * HUD_ROW_H)
        cols = (-HUD_CELL_W, 0.0, HUD_CELL_W)
        names = (("name", "t", "min_distance"), ("alive", "converged", "frozen"), FAULT_CELLS)
        return {names[r][c]: (cols[c], rows[r]) for r in range(3) for c in range(3)}

    def _top_panel(self, rows: int) -> None:
        """The translucent panel behind the top lines: 2 rows, or 3 with the faults' line."""
        top = HUD_DEPTH * math.tan(math.radians(FOV_DEG / 2))
        height = 0.15 + (rows - 2) * HUD_ROW_H
        self._set_object(f"{HUD}/panel", mo.flat_rect(3 * HUD_CELL_W + 0.08, height, PANEL_COLOR, 0.75,
                                                      "swarm_hud_panel", 0.0, top - 0.0025 - height / 2, -HUD_DEPTH))

    def _draw_overlay(self) -> None:
        """The static part of the overlay: the panels behind the text, and the legend (swatch + label)."""
        top = HUD_DEPTH * math.tan(math.radians(FOV_DEG / 2))
        z = -HUD_DEPTH
        self._top_panel(2)
        n_rows = -(-len(LEGEND) // 4)
        height = 0.07 + (n_rows - 1) * LEGEND_ROW_H
        self._set_object(f"{HUD}/legend/panel", mo.flat_rect(4 * LEGEND_CELL_W + 0.04, height, PANEL_COLOR, 0.75,
                                                             "swarm_legend_panel", 0.0, -top + 0.02 + height / 2, z))
        for k, (name, text, colour, opacity) in enumerate(LEGEND):
            x, y = (k % 4 - 1.5) * LEGEND_CELL_W, -top + 0.055 + (n_rows - 1 - k // 4) * LEGEND_ROW_H
            # the canvas centres its text: put the swatch just left of where the text starts (a
            # sans-serif letter is about half its font size wide)
            half_text = min(0.5, 0.26 * LEGEND_FONT_PX * len(text) / mo.TEXT_CANVAS) * LEGEND_CELL_W
            at = (x - half_text - 0.025, y, z)
            if name in RING_SWATCHES:  # what the scene draws: a ring
                swatch = mo.flat_ring(0.0095, 0.016, colour, f"swarm_legend_{name}_swatch", *at)
            else:
                swatch = mo.flat_rect(0.026, 0.026, colour, opacity, f"swarm_legend_{name}_swatch", *at, 1000)
            self._set_object(f"{HUD}/legend/{name}/swatch", swatch)
            self._set_object(f"{HUD}/legend/{name}/label", mo.label(
                text, LEGEND_CELL_W, LEGEND_FONT_PX, f"swarm_legend_{name}", x, y, z))

    def overlay_texts(self, t: float, q: np.ndarray, codes: np.ndarray, leader, stats: Stats | None) -> dict[str, str]:
        """The top panel's lines for this frame: cell name -> text. What `stats` leaves out comes from
        the frame: alive and frozen from the codes, converged from the slots and the leader (if the
        scene has them), the smallest distance from the poses of the live robots (a running minimum)."""
        stats = stats or Stats()
        n = len(q)
        live = (codes != DEAD) & np.isfinite(q).all(axis=1)
        alive = int(live.sum()) if stats.alive is None else stats.alive
        frozen = int((codes == FROZEN).sum()) if stats.frozen is None else stats.frozen
        converged = stats.converged
        if converged is None and leader is not None and self.scene.offsets is not None \
                and len(self.scene.offsets) == n:
            px = leader[0] + self.scene.offsets[:, 0] - q[:, 0]
            py = leader[1] + self.scene.offsets[:, 1] - q[:, 1]
            eth = np.abs((leader[2] - q[:, 2] + math.pi) % (2 * math.pi) - math.pi)
            converged = int((live & (np.hypot(px, py) < CONVERGED_POSITION_M) & (eth < CONVERGED_ANGLE_RAD)).sum())
        dmin = stats.min_distance
        if dmin is None and replace(stats, estop=None) == Stats():  # nothing given: the viewer's own running minimum
            pts = q[live, :2]
            if len(pts) >= 2:
                span = float(np.ptp(pts, axis=0).max()) + 1.0
                found = closest_pair(pts, span)
                if found is not None:
                    self._min_seen = min(self._min_seen, found[2])
            dmin = self._min_seen if math.isfinite(self._min_seen) else None
        texts = {
            "name": (self.scene.name or "swarm") if stats.estop is None else
                    f"E-STOP{': ' + stats.estop if stats.estop else ''}",
            "t": f"t = {t:.2f} s",
            "min_distance": "min distance –" if dmin is None else f"min distance {dmin:.3f} m",
            "alive": f"alive {alive} of {n}",
            "converged": "converged –" if converged is None else f"converged {converged} of {n}",
            "frozen": f"frozen {frozen}",
        }
        return {**texts, **self._fault_texts(codes)}

    def _fault_texts(self, codes: np.ndarray) -> dict[str, str]:
        """The third line (FAULT_CELLS), counted from the frame's codes and rings: shown once a robot is
        dead, hung, cut off or on stale data, or when the scene has scheduled faults; then kept for the
        run (a count back to 0 says the fault is over). Empty otherwise: a run without faults has no
        such line."""
        cut, stale = self._frame_marks
        if len(cut) != len(codes):
            cut, stale = np.zeros(len(codes), bool), None
        dead, hung = int((codes == DEAD).sum()), int((codes == HUNG).sum())
        n_cut, n_stale = int(cut.sum()), None if stale is None else int(stale.sum())
        if not self._fault_row and (dead or hung or n_cut or n_stale or self.scene.timeline):
            self._fault_row = True
        if not self._fault_row:
            return {}
        return {"dead_hung": f"dead {dead}  hung {hung}",
                "stopped_cut": f"stopped {int((codes == STOPPED).sum())}  cut off {n_cut}",
                "stale_data": "stale data –" if n_stale is None else f"stale data {n_stale}"}

    def refresh_overlay(self) -> None:
        """Send the overlay's lines that changed since they were last sent (draw() does it at most every
        HUD_PERIOD_S; call this after the last frame so that the overlay shows it)."""
        if not self.overlay:
            return
        self._hud_at = self.clock()
        layout = self._hud_layout()
        rows = 3 if any(name in self._hud_want for name in FAULT_CELLS) else 2
        if rows != self._hud_rows:  # the faults' line comes (or a new run took it away)
            self._top_panel(rows)
            for name in FAULT_CELLS:
                if name not in self._hud_want and name in self._hud_sent:
                    self._delete(f"{HUD}/{name}")
                    del self._hud_sent[name]
            self._hud_rows = rows
        for name, text in self._hud_want.items():
            if self._hud_sent.get(name) != text:
                x, y = layout[name]
                self._set_object(f"{HUD}/{name}", mo.label(text, HUD_CELL_W, HUD_FONT_PX, f"swarm_hud_{name}", x, y,
                                                           -HUD_DEPTH))
                self._hud_sent[name] = text

    def reframe(self) -> None:
        """Frame the camera on the next frame, whatever the user's zoom (a replay that jumps)."""
        self._cam_dist, self._cam_time = 0.0, -math.inf
        self._centre = None

    def _frame_centre(self, q: np.ndarray, leader) -> np.ndarray:
        pts = q[:, :2] if leader is None else np.vstack([q[:, :2], [leader[:2]]])
        target = 0.5 * (pts.min(axis=0) + pts.max(axis=0)) if len(pts) else np.zeros(2)
        if self._centre is None or np.abs(target - self._centre).max() > 20.0:
            self._centre = target
        else:  # follow smoothly: no jitter when one robot moves
            self._centre = self._centre + 0.25 * (target - self._centre)
        return self._centre

    def _frame_camera(self, q: np.ndarray, leader, centre: np.ndarray) -> None:
        """Move the camera back (or in) when the swarm's size changed by more than 30 %, at most
        once a second, so a user's own zoom survives in between."""
        pts = q[:, :2] if leader is None else np.vstack([q[:, :2], [leader[:2]]])
        extent = max(3.0, float(np.sqrt(((pts - centre) ** 2).sum(axis=1)).max()) + 1.0) if len(pts) else 10.0
        dist = 1.15 * extent / math.tan(math.radians(FOV_DEG / 2))
        now = time.monotonic()
        if self._cam_dist and abs(dist / self._cam_dist - 1) < 0.3 or now - self._cam_time < 1.0:
            return
        self._cam_dist, self._cam_time = dist, now
        up = math.radians(60.0)  # elevation of the eye above the ground
        eye = (0.0, -dist * math.cos(up), dist * math.sin(up))
        # the camera's parent frame is y-up: world (x, y, z) -> (x, z, -y)
        self._send({"type": "set_property", "path": CAMERA, "property": "position",
                    "value": [eye[0], eye[2], -eye[1]]})

    def _update_trails(self, t: float, q: np.ndarray) -> None:
        n = len(q)
        if self._trail is None or self._trail.shape[1] != n:
            length = int(max(2, min(150, TRAIL_VERTICES // max(1, 2 * n))))
            self._trail = np.repeat(q[None, :, :2], length, axis=0)
            self._trail_k, self._trail_t = 0, t
        if t - self._trail_t >= TRAIL_SAMPLE_S:
            self._trail_k = (self._trail_k + 1) % len(self._trail)
            self._trail[self._trail_k] = q[:, :2]
            self._trail_t = t
        self._trail_q = q
        if time.monotonic() - self._trail_sent >= TRAIL_PERIOD_S:
            self.send_trails()

    def send_trails(self) -> None:
        """Send the trails now (draw() does it once a second; a replay that jumps calls this)."""
        if self._trail is None:
            return
        self._trail_sent = time.monotonic()
        tr = np.roll(self._trail, -(self._trail_k + 1), axis=0)  # oldest first
        tr = np.concatenate([tr, self._trail_q[None, :, :2]], axis=0)  # up to the robot itself
        seg = np.stack([tr[:-1], tr[1:]], axis=2).transpose(1, 0, 2, 3).reshape(-1, 2)  # (N*(L)*2, 2)
        pos = np.c_[seg, np.full(len(seg), 0.01)]
        self._set_object(f"{ROOT}/trails", mo.mesh_object("LineSegments", mo.geometry(pos),
                                                   mo.material("LineBasicMaterial", TRAIL_COLOR), "swarm_trails"))

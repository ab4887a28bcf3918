"""The swarm drawn in meshcat: one InstancedMesh per frame, whatever the number of robots.

    viewer = Viewer(server, SceneInfo.from_scenario(scn))    # a MeshcatServer, its client, or a meshcat Visualizer
    viewer.draw(t, q, codes, leader=(x, y, theta))           # q (N, 3) x, y, theta; codes (N,) TRACKING ...

The drawing knows nothing of zenoh, processes or where the poses come from: `swarm.view.watch` feeds it
from a live swarm, `swarm sim --viz` from the simulator, a replay from a recording.

Scene (z up, metres): a ground with a 2 m grid; obstacles (r solid, R translucent with its rim);
the robots, coloured by state with a dark arrow for the heading (optionally their R ring); the
formation as ghosts: the leader (translucent arrow) and every slot (translucent disc at leader +
offset: the law adds the offsets unrotated, DESIGN.md section 2); trails (one LineSegments, resent
once a second). A robot's body has radius r/2, so two bodies touch exactly when their centres are
r apart: a collision.

Per frame: one set_object (every robot in one InstancedMesh, with per-instance colour) and three
set_transform (the scene root, the formation, the leader), whatever N; meshcat 0.3.2 has no batch
command and each command is a ZMQ round trip (recipes/meshcat-browser.md). A static twin of the
robots' mesh stays in the scene so that three.js keeps the shader program when set_object
disposes the old material (without it the program is recompiled every frame). The camera cannot
be aimed through meshcat 0.3.2 (its orbit target stays at the origin), so the scene moves
instead: the root is translated to put the swarm's centre at the origin, and the camera is moved
back when the swarm grows or shrinks a lot.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from swarm.view import meshcat_objects as mo
from swarm.view.meshcat_objects import poses_to_matrices

# Robot states, in increasing priority: a robot shows the highest that applies.
TRACKING, FROZEN, STALE, STOPPED, DEAD = 0, 1, 2, 3, 4
STATE_NAMES = ("tracking", "frozen", "stale", "stopped", "dead")
# 0xRRGGBB per state: tracking green, frozen orange, stale grey, stopped purple, dead black.
STATE_COLORS = (0x2CA02C, 0xFF7F0E, 0x9E9E9E, 0x9467BD, 0x111111)
STALE_AFTER_S = 1.0  # wall seconds without a status before a robot shows as stale

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


def rgb(hex_color: int) -> tuple[float, float, float]:
    return ((hex_color >> 16) & 255) / 255.0, ((hex_color >> 8) & 255) / 255.0, (hex_color & 255) / 255.0


PALETTE = np.array([rgb(c) for c in STATE_COLORS], np.float32)  # (5, 3) in [0, 1]


def state_codes(alive: np.ndarray, stopped: np.ndarray, frozen: np.ndarray, status_age_s: np.ndarray,
                stale_after_s: float = STALE_AFTER_S) -> np.ndarray:
    """(N,) state codes from the flags: dead (not alive) > stopped > stale (last status older than
    stale_after_s wall seconds) > frozen > tracking. All inputs (N,); ages in seconds."""
    codes = np.full(len(alive), TRACKING, np.int8)
    codes[np.asarray(frozen, bool)] = FROZEN
    codes[np.asarray(status_age_s, float) > stale_after_s] = STALE
    codes[np.asarray(stopped, bool)] = STOPPED
    codes[~np.asarray(alive, bool)] = DEAD
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

    def __post_init__(self) -> None:
        if not (0 < self.r < self.R and math.isfinite(self.R)):
            raise ValueError(f"radii must satisfy 0 < r < R, got r = {self.r}, R = {self.R}")
        obs = np.asarray(self.obstacles, float).reshape(-1, 4)
        object.__setattr__(self, "obstacles", obs)
        if self.offsets is not None:
            object.__setattr__(self, "offsets", np.asarray(self.offsets, float).reshape(-1, 2))

    @classmethod
    def from_scenario(cls, scn) -> "SceneInfo":
        return cls(r=float(scn.r), R=float(scn.R), offsets=np.array(scn.offsets, float),
                   obstacles=np.array(scn.obstacles, float), leader_table=scn.leader.table(), name=scn.name)

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

    def __init__(self, target, scene=None, rings: bool = False, trails: bool = True):
        self.sink = mo.sink_of(target)
        self.rings, self.trails = rings, trails
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

    def draw(self, t: float, q: np.ndarray, codes: np.ndarray, leader: tuple[float, float, float] | None = None) -> None:
        """One frame at simulated time t [s]: q (N, 3) poses, codes (N,) states (TRACKING ...),
        leader (x, y, theta) or None (then the scene's leader table is used, if any)."""
        started = time.perf_counter()
        q = np.asarray(q, float).reshape(-1, 3)
        codes = np.asarray(codes).reshape(-1)
        if len(codes) != len(q):
            raise ValueError(f"{len(q)} poses but {len(codes)} state codes")
        if leader is None:
            leader = self.scene.leader_pose(t)
        if t < self._last_t:  # a new run (or a replay rewound): forget the trails
            self._trail = None
        self._last_t = t
        centre = self._frame_centre(q, leader)
        if self._ground_at is None or np.abs(centre - self._ground_at).max() > 0.5 * GROUND_HALF:
            self._draw_ground(centre)
        self._set_transform(ROOT, mo.translation(-centre[0], -centre[1]))
        self._frame_camera(q, leader, centre)
        colours = PALETTE[np.clip(codes, 0, len(PALETTE) - 1).astype(np.intp)]
        self._set_object(f"{ROOT}/robots", mo.instanced(self._robot_geometry, self._robot_material, "swarm_robots",
                                                      poses_to_matrices(q), colours))
        show = leader is not None
        if show != self._formation_shown:
            self._send({"type": "set_property", "path": f"{ROOT}/formation", "property": "visible", "value": show})
            self._formation_shown = show
        if show:
            self._set_transform(f"{ROOT}/formation", mo.translation(leader[0], leader[1]))
            self._set_transform(f"{ROOT}/formation/leader", mo.translation(0.0, 0.0, 0.0, leader[2]))
        if self.trails:
            self._update_trails(t, q)
        self.frames += 1
        self.costs.append(time.perf_counter() - started)
        if len(self.costs) > 1000:
            del self.costs[:500]

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

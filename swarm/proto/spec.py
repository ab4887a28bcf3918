"""The wire format's numbers and tables: the protocol version, the size and value bounds, every flat kind's fields
(wire name and type, and those a sender may leave out), the wire names of Python's fields, and the bounds the hot
decoders check. swarm.proto.protocol generates its encoders and decoders (msgspec's wire structs) from these tables."""

from __future__ import annotations

from swarm.proto.messages import KINDS

VERSION = 1
MAX_PAYLOAD = 64 << 10  # bytes: any message but the large kinds (a state is ~100 bytes); larger is refused unread
MAX_LARGE_PAYLOAD = 16 << 20  # bytes: snapshot, obstacles, run (a snapshot of 100 000 robots is ~10 MB)
LARGE_KINDS = ("snapshot", "obstacles", "run", "bodies")
MAX_ROBOTS = 100_000
MAX_SPEED = 100.0  # m/s: |vel| of any command, reference or snapshot
MAX_TURN = 100.0  # rad/s: |w|
MAX_COORD = 1e6  # m: |x|, |y| of any position (poses, states, references, obstacles, offsets)
MAX_ANGLE = 1e6  # rad: |theta| (the leader's heading is not wrapped)
MAX_TIME = 1e9  # s: |t|
MAX_TEXT = 256  # characters of a short string field (run id, digest)

_SPEC: dict[str, tuple[tuple[str, str], ...]] = {
    "ref": (("t", "n"), ("seq", "i"), ("x", "n"), ("y", "n"), ("theta", "n"), ("vel", "n"), ("w", "n")),
    "pose": (("t", "n"), ("seq", "i"), ("x", "n"), ("y", "n"), ("theta", "n"), ("cmd", "n")),
    "cmd": (("t", "n"), ("seq", "i"), ("vel", "n"), ("w", "n"), ("until", "n")),
    "state": (("id", "id"), ("t", "n"), ("seq", "i"), ("x", "n"), ("y", "n"), ("theta", "n"), ("r", "n"),
              ("R", "n"), ("frozen", "b"), ("stop", "n"), ("still", "n")),
    "status": (("t", "n"), ("ex", "n"), ("ey", "n"), ("etheta", "n"), ("frozen", "b"), ("neighbours", "i"),
               ("stale", "i"), ("bad", "i"), ("held", "n")),
    "clock": (("t", "n"), ("seq", "i"), ("epoch", "n"), ("speed", "n")),
    "config": (("id", "id"), ("x", "n"), ("y", "n"), ("theta", "n"), ("dx", "n"), ("dy", "n"), ("r", "n"),
               ("R", "n"), ("k1", "n"), ("k2", "n"), ("k3", "n"), ("tu", "n"), ("vt", "n"), ("threshold", "i"),
               ("governor", "b"), ("dt", "n"), ("sense", "n"), ("reach", "n"), ("lockstep", "b"), ("robots", "i"),
               ("v_max", "n"), ("w_max", "n"), ("run", "s"), ("digest", "s"), ("arena", "b"), ("xmin", "n"),
               ("xmax", "n"), ("ymin", "n"), ("ymax", "n"), ("v_bound", "n"), ("law", "s"),
               ("law_sha256", "s"), ("law_params", "f"), ("law_memory", "i")),
    "progress": (("t", "n"), ("seq", "i"), ("duration", "n"), ("robots", "i"), ("alive", "i"),
                 ("converged", "i"), ("frozen", "i"), ("min_distance", "n"), ("misses", "i"), ("bad", "i"),
                 ("collisions", "i"), ("overruns", "i"), ("min_obstacle", "n"), ("position_error", "n"),
                 ("orientation_error", "n"), ("converged_at", "n"), ("last_freeze", "n"), ("dropped", "i"),
                 ("hung", "i"), ("held", "n"), ("stranded", "i")),
    "run": (("run", "s"), ("digest", "s"), ("robots", "i"), ("lockstep", "b"), ("scenario", "S")),
    "estop": (("t", "n"), ("seq", "i"), ("engaged", "b"), ("reason", "s")),
    "faultstats": (("t", "n"), ("seq", "i"), ("dropped_state", "i"), ("dropped_pose", "i"), ("dropped_ref", "i"),
                   ("delayed_state", "i"), ("delayed_pose", "i"), ("delayed_ref", "i"), ("max_age", "n"),
                   ("frozen", "b")),
    "claim": (("id", "id"), ("claim", "s"), ("granted", "b"), ("robots", "i"), ("reason", "s")),
    "proc": (("role", "s"), ("id", "i"), ("host", "s"), ("pid", "i"), ("started", "n"), ("run", "s"), ("version", "s")),
}
# Fields a sender may leave out (the real-time safety fields: docs/protocol.md); absent, the message's field is
# None. Encoders leave out a None one; the decoders take a map with or without them (an explicit nil is refused).
_OPTIONAL: dict[str, tuple[str, ...]] = {"pose": ("cmd",), "cmd": ("until",), "state": ("stop", "still"),
                                         "status": ("held",),
                                         "config": ("law", "law_sha256", "law_params", "law_memory")}
# The key-space contract names both the protocol version and the linear velocity of ref and cmd
# "v"; one map cannot hold both. "v" stays the version (a decoder needs it before the kind);
# on the wire the linear velocity is "vel" (docs/protocol.md). In Python it is still .v.
_WIRE = {"v": "vel"}
_FIELD = {"vel": "v"}
_WIRE_NAMES = {k: tuple((f, _WIRE.get(f, f)) for f in cls.__struct_fields__) for k, cls in KINDS.items()}
MAX_LAW_PARAMS = 64  # numbers in a config's law_params
MAX_LAW_MEMORY = 1024  # floats of a user law's memory per robot

_SNAP_FIELDS = ("id", "x", "y", "theta", "v", "w", "stopped", "alive")

# The kinds every robot (or the world) decodes every control period, with the physical bounds of their
# _CHECK functions: |field| <= bound (which also says finite); a state also has 0 < r < R.
_HOT_BOUNDS: dict[str, tuple[tuple[str, float], ...]] = {
    "state": (("t", MAX_TIME), ("x", MAX_COORD), ("y", MAX_COORD), ("theta", MAX_ANGLE), ("R", MAX_COORD),
              ("stop", MAX_COORD), ("still", MAX_TIME)),
    "pose": (("t", MAX_TIME), ("x", MAX_COORD), ("y", MAX_COORD), ("theta", MAX_ANGLE), ("cmd", MAX_TIME)),
    "ref": (("t", MAX_TIME), ("x", MAX_COORD), ("y", MAX_COORD), ("theta", MAX_ANGLE), ("v", MAX_SPEED),
            ("w", MAX_TURN)),
    "cmd": (("t", MAX_TIME), ("v", MAX_SPEED), ("w", MAX_TURN), ("until", MAX_TIME)),
}

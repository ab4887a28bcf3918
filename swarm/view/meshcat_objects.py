"""three.js objects as meshcat messages, built directly (no meshcat classes on the hot path).

    geo = geometry(positions (K, 3), index (T*3,), colours (K, 3))      # a BufferGeometry
    obj = instanced(geo, material(vertex_colors=True), "name", matrices (N, 16), colours (N, 3))
    obj = label("t = 12.3 s", width, font_px, "name", x, y, z)           # text (meshcat's "_text" texture)
    obj = flat_rect(w, h, colour, opacity, "name", x, y, z)             # a swatch (flat_ring: a ring)
    sink.send(Command({"type": "set_object", "path": "/swarm/robots", "object": obj}))

Arrays go as msgpack extension types (0x17 Float32Array, 0x16 Uint32Array), as meshcat's own
geometry does. An InstancedMesh is what three.js r129 (bundled with meshcat 0.3.2) loads from
`count`, `instanceMatrix` (column-major 4x4 per instance) and `instanceColor`; frustum culling is
off because three.js r129 bounds an InstancedMesh by its one geometry, not by its instances.
A sink is anything with send(command): meshcat's ViewerWindow, swarm.view.meshcat_server.MeshcatClient,
or CommandLog (packs and counts, sends nothing: tests and cost measurements).
"""

from __future__ import annotations

import math
import uuid

import numpy as np


# --------------------------------------------------------------------------- messages


class Command:
    """A lowered meshcat command (what meshcat's own command classes produce)."""

    __slots__ = ("data",)

    def __init__(self, data: dict):
        self.data = data

    def lower(self) -> dict:
        return self.data


def f32(a: np.ndarray, item: int) -> dict:
    import umsgpack

    a = np.ascontiguousarray(a, np.float32)
    return {"itemSize": item, "type": "Float32Array", "normalized": False, "array": umsgpack.Ext(0x17, a.tobytes())}


def u32(a: np.ndarray) -> dict:
    import umsgpack

    a = np.ascontiguousarray(a, np.uint32)
    return {"itemSize": 1, "type": "Uint32Array", "normalized": False, "array": umsgpack.Ext(0x16, a.tobytes())}


def geometry(pos: np.ndarray, index: np.ndarray | None = None, color: np.ndarray | None = None,
             uv: np.ndarray | None = None) -> dict:
    """A BufferGeometry: pos (K, 3) [m], index (T*3,), color (K, 3) in [0, 1], uv (K, 2) texture coordinates."""
    attrs = {"position": f32(pos, 3)}
    if color is not None:
        attrs["color"] = f32(color, 3)
    if uv is not None:
        attrs["uv"] = f32(uv, 2)
    data: dict = {"attributes": attrs}
    if index is not None:
        data["index"] = u32(index)
    return {"uuid": str(uuid.uuid4()), "type": "BufferGeometry", "data": data}


def material(kind: str = "MeshBasicMaterial", color: int = 0xFFFFFF, opacity: float = 1.0,
              vertex_colors: bool = False, depth_write: bool = True) -> dict:
    return {"uuid": str(uuid.uuid4()), "type": kind, "color": color, "side": 2, "opacity": opacity,
            "transparent": opacity < 1.0, "depthWrite": depth_write, "vertexColors": vertex_colors}


# --------------------------------------------------------------------------- text
#
# meshcat 0.3.2 has no text or HTML command, but its loader knows one texture type of its own, "_text":
# the browser draws the text, centred, in black, on a transparent 256 x 256 canvas (one line; a text
# wider than the canvas is drawn smaller), with its baseline at the canvas's middle row. A label is a
# flat quad that shows only the band of that canvas around the text, so the quad is as wide as the
# canvas and a few text heights tall.

TEXT_CANVAS = 256  # px, the canvas of a "_text" texture (fixed by meshcat)


def text_texture(text: str, font_px: int, font_face: str = "sans-serif") -> dict:
    """meshcat's "_text" texture: `text` drawn at font_px pixels on the 256 x 256 canvas."""
    return {"uuid": str(uuid.uuid4()), "type": "_text", "text": text, "font_size": int(font_px),
            "font_face": font_face}


def text_band(font_px: int) -> tuple[float, float]:
    """(top, bottom) canvas rows [px] around a line of text at font_px: ascenders and descenders."""
    mid = TEXT_CANVAS / 2
    return mid - 0.95 * font_px, mid + 0.35 * font_px


def label(text: str, width: float, font_px: int, name: str, x: float, y: float, z: float,
          render_order: int = 1000) -> dict:
    """A quad `width` wide (its height follows the text band) centred at (x, y, z) showing `text`, drawn
    over everything (no depth test). The text is also in the object's userData (for tests and tools)."""
    top, bottom = text_band(font_px)
    h = width * (bottom - top) / TEXT_CANVAS
    v0, v1 = 1.0 - bottom / TEXT_CANVAS, 1.0 - top / TEXT_CANVAS  # a canvas texture is flipped: v = 1 on top
    pos = np.array([[-width / 2, -h / 2, 0.0], [width / 2, -h / 2, 0.0], [width / 2, h / 2, 0.0],
                    [-width / 2, h / 2, 0.0]])
    uv = np.array([[0.0, v0], [1.0, v0], [1.0, v1], [0.0, v1]])
    tex = text_texture(text, font_px)
    mat = {**material(depth_write=False), "transparent": True, "map": tex["uuid"], "depthTest": False}
    obj = mesh_object("Mesh", geometry(pos, np.array([0, 1, 2, 0, 2, 3]), uv=uv), mat, name,
                      matrix=translation(x, y, z), renderOrder=render_order, userData={"text": text})
    obj["textures"] = [tex]
    return obj


def flat_rect(width: float, height: float, color: int, opacity: float, name: str, x: float, y: float, z: float,
              render_order: int = 999) -> dict:
    """A plain rectangle centred at (x, y, z), drawn over everything (a swatch, or a panel behind text)."""
    pos = np.array([[-width / 2, -height / 2, 0.0], [width / 2, -height / 2, 0.0], [width / 2, height / 2, 0.0],
                    [-width / 2, height / 2, 0.0]])
    # transparent even when opaque: three.js draws opaque objects first, so an opaque swatch would end
    # up under a translucent panel whatever their render order
    mat = {**material(color=color, opacity=opacity, depth_write=False), "transparent": True, "depthTest": False}
    return mesh_object("Mesh", geometry(pos, np.array([0, 1, 2, 0, 2, 3])), mat, name,
                       matrix=translation(x, y, z), renderOrder=render_order)


def flat_ring(r_in: float, r_out: float, color: int, name: str, x: float, y: float, z: float,
              render_order: int = 1000) -> dict:
    """A flat ring (radii in m) centred at (x, y, z) facing the camera, drawn over everything (a legend swatch)."""
    pos, idx = annulus(r_in, r_out, 0.0, 32)
    mat = {**material(color=color, depth_write=False), "transparent": True, "depthTest": False}
    return mesh_object("Mesh", geometry(pos, idx), mat, name, matrix=translation(x, y, z), renderOrder=render_order)


def mesh_object(kind: str, geometry: dict, material: dict, name: str, **extra) -> dict:
    obj = {"uuid": str(uuid.uuid4()), "type": kind, "geometry": geometry["uuid"], "material": material["uuid"],
           "matrix": [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0], "name": name, **extra}
    return {"metadata": {"version": 4.5, "type": "Object"}, "geometries": [geometry], "materials": [material],
            "object": obj}


def instanced(geometry: dict, material: dict, name: str, matrices: np.ndarray, colors: np.ndarray | None) -> dict:
    """An InstancedMesh of len(matrices) copies; matrices (K, 16) column-major, colors (K, 3) or None."""
    extra = {"count": int(len(matrices)), "instanceMatrix": f32(matrices, 16), "frustumCulled": False}
    if colors is not None:
        extra["instanceColor"] = f32(colors, 3)
    return mesh_object("InstancedMesh", geometry, material, name, **extra)


def poses_to_matrices(q: np.ndarray, scale: np.ndarray | float = 1.0, z: float = 0.0) -> np.ndarray:
    """(N, 16) float32 column-major transforms: rotation theta about z, then (x, y, z); uniform scale."""
    q = np.asarray(q, float).reshape(-1, 3)
    c, s = np.cos(q[:, 2]) * scale, np.sin(q[:, 2]) * scale
    m = np.zeros((len(q), 16), np.float32)
    m[:, 0], m[:, 1], m[:, 4], m[:, 5] = c, s, -s, c
    m[:, 10] = scale
    m[:, 12], m[:, 13], m[:, 14], m[:, 15] = q[:, 0], q[:, 1], z, 1.0
    return m


def translation(x: float, y: float, z: float = 0.0, theta: float = 0.0) -> list[float]:
    c, s = math.cos(theta), math.sin(theta)
    return [c, s, 0.0, 0.0, -s, c, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, x, y, z, 1.0]


# --------------------------------------------------------------------------- shapes


def disc(radius: float, z: float, segments: int = 24) -> tuple[np.ndarray, np.ndarray]:
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    pos = np.vstack([[0.0, 0.0, z], np.c_[radius * np.cos(a), radius * np.sin(a), np.full(segments, z)]])
    idx = np.array([[0, 1 + k, 1 + (k + 1) % segments] for k in range(segments)]).ravel()
    return pos, idx


def annulus(r_in: float, r_out: float, z: float, segments: int = 48) -> tuple[np.ndarray, np.ndarray]:
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = lambda r: np.c_[r * np.cos(a), r * np.sin(a), np.full(segments, z)]  # noqa: E731
    pos = np.vstack([ring(r_in), ring(r_out)])
    idx = []
    for k in range(segments):
        j = (k + 1) % segments
        idx += [k, segments + k, segments + j, k, segments + j, j]
    return pos, np.array(idx)


def cylinder_side(radius: float, height: float, segments: int = 24) -> tuple[np.ndarray, np.ndarray]:
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    lo = np.c_[radius * np.cos(a), radius * np.sin(a), np.zeros(segments)]
    hi = lo + [0.0, 0.0, height]
    idx = []
    for k in range(segments):
        j = (k + 1) % segments
        idx += [k, j, segments + j, k, segments + j, segments + k]
    return np.vstack([lo, hi]), np.array(idx)


def arrow(length: float, width: float, z: float) -> tuple[np.ndarray, np.ndarray]:
    """A flat arrow head pointing along +x, its tip at `length`."""
    pos = np.array([[length, 0.0, z], [-0.45 * length, 0.5 * width, z], [-0.2 * length, 0.0, z],
                    [-0.45 * length, -0.5 * width, z]])
    return pos, np.array([0, 1, 2, 0, 2, 3])


def merge(parts: list[tuple[np.ndarray, np.ndarray, float]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge (pos, index, grey) parts into one indexed mesh with per-vertex grey colours."""
    pos, idx, col, base = [], [], [], 0
    for p, i, grey in parts:
        pos.append(p)
        idx.append(i + base)
        col.append(np.full((len(p), 3), grey))
        base += len(p)
    return np.vstack(pos), np.concatenate(idx), np.vstack(col)


# --------------------------------------------------------------------------- sinks


class CommandLog:
    """A sink that packs every command as the real client does and keeps (kind, path, bytes), but
    sends nothing: for tests and for measuring the drawing's own cost without a server."""

    def __init__(self) -> None:
        self.commands: list[tuple[str, str, int]] = []
        self.last: dict[str, dict] = {}

    def send(self, command) -> None:
        import umsgpack

        data = command.lower()
        packed = umsgpack.packb(data)
        self.commands.append((data["type"], data.get("path", ""), len(packed)))
        self.last[data.get("path", "")] = data


def sink_of(target):
    """The object with send(command): a MeshcatServer's client, a meshcat Visualizer's window, or itself."""
    if hasattr(target, "client") and hasattr(target, "web_url"):
        return target.client
    if hasattr(target, "window") and hasattr(target.window, "send"):
        return target.window
    if not hasattr(target, "send"):
        raise TypeError(f"cannot draw into {type(target).__name__}: expected a MeshcatServer, a meshcat "
                        "Visualizer or an object with send(command)")
    return target

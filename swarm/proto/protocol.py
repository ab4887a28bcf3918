"""Messages of docs/protocol.md and their one versioned msgpack codec.

    payload = encode(Cmd(t=1.0, seq=50, v=0.4, w=-0.1))
    msg = decode(payload, kind="cmd", key_id=7)      # raises ProtocolError if anything is off

Every payload is a msgpack map {"v": 1, "kind": ..., fields}. decode() validates at the
boundary: size, msgpack, version, kind, the exact set of fields, types (bool is not a
number), finite numbers, ranges (ids and seq >= 0, 0 < r < R, speeds, coordinates and times
within physical bounds), and the id in the key equal to the id in the payload; with `limits`
(a Limits from the scenario) also the scenario's ids, radii, speed bounds and arena. Anything
wrong raises ProtocolError with a reason, and nothing else: a crafted payload of any shape
cannot make decode() raise another exception. A process drops and counts such a message
(swarm.proto.protocol.BadMessages) and goes on. The bounds and the windows that receivers keep
per sender (swarm.proto.window) are in docs/protocol.md.

The parts live in modules of their own, and everything other modules use is re-exported here (import it from
here): swarm.proto.messages (the dataclasses, ProtocolError), swarm.proto.spec (the version, the bounds, every
kind's fields on the wire), swarm.proto.checks (the checks of every field and kind, Limits) and
swarm.proto.refusals (BadMessages, Claims). This module is the codec: encode(), decode() and decoder(). msgspec
writes every message and reads every flat kind through the kind's wire struct (_wire_struct: every type and bound
checked as it reads); what it does not take, and the nested kinds, go the general way (msgpack, then each check in
turn), which refuses naming the reason. No msgpack is parsed by hand.
"""

from __future__ import annotations

import math
from operator import attrgetter, methodcaller
from typing import TYPE_CHECKING, Annotated, Any, Literal, overload

import msgpack
import msgspec
from msgspec.structs import replace as replace  # a message with some fields changed: replace(cfg, v_max=0.2)
from swarm.core.errors import SwarmError
# re-exported (X as X): what other modules, the tests and the benchmarks take from here
from swarm.proto.checks import PROC_ROLES as PROC_ROLES
from swarm.proto.checks import Limits as Limits
from swarm.proto.messages import (EVENTS as EVENTS, KINDS as KINDS, Bodies as Bodies, Body as Body, Claim as Claim,
                                  Clock as Clock, Cmd as Cmd, Config as Config, Estop as Estop, Event as Event,
                                  FaultStats as FaultStats, Obstacle as Obstacle, Obstacles as Obstacles, Pose as Pose,
                                  Proc as Proc, Progress as Progress, ProtocolError as ProtocolError, Ref as Ref,
                                  RobotSnap as RobotSnap, Run as Run, Snapshot as Snapshot, State as State,
                                  Status as Status, kind_of as kind_of)
from swarm.proto.refusals import REFUSALS_PER_S_MAX as REFUSALS_PER_S_MAX
from swarm.proto.refusals import BadMessages as BadMessages
from swarm.proto.refusals import Claims as Claims
from swarm.proto.spec import (LARGE_KINDS as LARGE_KINDS, MAX_ANGLE as MAX_ANGLE, MAX_COORD as MAX_COORD,
                              MAX_LARGE_PAYLOAD as MAX_LARGE_PAYLOAD, MAX_LAW_MEMORY as MAX_LAW_MEMORY,
                              MAX_LAW_PARAMS as MAX_LAW_PARAMS, MAX_PAYLOAD as MAX_PAYLOAD, MAX_ROBOTS as MAX_ROBOTS,
                              MAX_SPEED as MAX_SPEED, MAX_TEXT as MAX_TEXT, MAX_TIME as MAX_TIME,
                              MAX_TURN as MAX_TURN, VERSION as VERSION)
# the codec's own
from swarm.proto.checks import _CHECK, _READ, _bodies, _event, _obstacles, _snapshot, _spec_fields
from swarm.proto.messages import _KIND_OF
from swarm.proto.spec import _FIELD, _HOT_BOUNDS, _OPTIONAL, _SNAP_FIELDS, _SPEC, _WIRE, _WIRE_NAMES
from swarm.proto import window as _window
from swarm.proto.window import Window

if TYPE_CHECKING:
    from collections.abc import Callable
    from typing import Protocol, TypeVar

    from swarm.proto.messages import HotMessage, Message

# a robot's loops over its messages, compiled where setup.py found a C compiler (None: the Python loops; so under
# SWARM_PURE_PYTHON): swarm.proto.window decides it, once; the agent and the bus read protocol._wire (tests set it)
_wire = _window.LOOPS

if _wire is not None:  # what the loops read of Python objects, handed over here (they look nothing up by name)
    _wire.setup(attrgetter("id", "t", "seq", "x", "y", "r", "R"), Window.take,
                attrgetter("key_expr", "payload", "attachment"), methodcaller("to_bytes"))

if TYPE_CHECKING:
    _M_co = TypeVar("_M_co", covariant=True)

    class Decoder(Protocol[_M_co]):
        """What decoder() returns: f(payload, key_id=None) -> the message (ProtocolError if anything is off)."""

        def __call__(self, payload: bytes, key_id: int | None = None, /) -> _M_co: ...


# --------------------------------------------------------------------------- encoding


def encode(msg: Any) -> bytes:
    """msgpack bytes of a message (no validation: messages are built by this process), written by msgspec: a flat
    kind from its wire struct (_wire_struct), a nested one from a dict in the same key order."""
    cls = type(msg)
    fast = _FAST_ENCODE.get(cls)
    if fast is not None:
        return fast(msg)
    kind = _KIND_OF.get(cls)
    if kind is None:
        raise TypeError(f"not a protocol message: {cls.__name__}")
    if kind in _SPEC:  # a flat kind's first message: generate its encoder (kept for the next ones)
        fast = _FAST_ENCODE[cls] = _compile_encode(kind)
        return fast(msg)
    d: dict[str, Any] = {"v": VERSION, "kind": kind}
    if kind == "obstacles":
        d["obstacles"] = [{"x": o.x, "y": o.y, "r": o.r, "R": o.R} for o in msg.obstacles]
    elif kind == "event":
        d.update(t=msg.t, seq=msg.seq, event=msg.event, robots=list(msg.robots), detail=msg.detail)
    elif kind == "bodies":
        d.update(t=msg.t, seq=msg.seq, bodies=[{"id": b.id, "x": b.x, "y": b.y, "r": b.r, "R": b.R} for b in msg.bodies],
                 returning=[{"id": b.id, "x": b.x, "y": b.y, "r": b.r, "R": b.R} for b in msg.returning])
    elif kind == "snapshot":
        d.update(t=msg.t, seq=msg.seq,
                 robots=[{f: getattr(s, f) for f in _SNAP_FIELDS} for s in msg.robots])
    return _packb(d)


def _enc_hook(obj: Any) -> Any:
    """What msgspec does not write itself, as msgpack.packb writes it: a float subclass (numpy's float64) as a float,
    an int subclass as an int, a str subclass as a str; anything else is not a field of a message."""
    if isinstance(obj, float):
        return float(obj)
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, str):
        return str(obj)
    raise TypeError(f"a message field cannot be a {type(obj).__name__}")


_packb = msgspec.msgpack.Encoder(enc_hook=_enc_hook).encode  # the bytes msgpack.packb(x, use_bin_type=True) writes


def _wire_struct(kind: str, limits: Limits | None = None, *, typed: bool = True) -> type[msgspec.Struct]:
    """A flat kind's map on the wire as a msgspec struct: "v" and "kind", then its fields by wire name in the
    encoder's order (the message's), the optional ones last (typed: None when absent, an explicit nil refused;
    else UNSET, left out when written).
    typed: every field's type and bound as decode() holds them (numbers finite and, for the kinds of every period,
    within _HOT_BOUNDS and the scenario's `limits`; ints in range; strings bounded), for decoding; else Any, for
    writing (what a message holds is written as it is)."""
    types = dict(_SPEC[kind])
    optional = _OPTIONAL.get(kind, ())
    bounds = {_WIRE.get(n, n): b for n, b in _HOT_BOUNDS.get(kind, ())}
    lims: dict[str, tuple[float, float]] = {}
    if limits is not None:  # as plain floats (a bound of 9 and one of 9.0 are one Meta to typing's cache)
        tol = 1 + 1e-9  # as Limits.check
        if kind == "state":
            lims["R"] = (-_FINITE, float(limits.radius) * tol)
        if kind == "cmd":
            lims["vel"] = (-(float(limits.v_max) * tol), float(limits.v_max) * tol)
            lims["w"] = (-(float(limits.w_max) * tol), float(limits.w_max) * tol)
        if limits.bounds is not None and kind in ("state", "pose"):
            xmin, xmax, ymin, ymax = map(float, limits.bounds)
            lims["x"], lims["y"] = (xmin, xmax), (ymin, ymax)

    def typ(wire: str) -> Any:
        if not typed:
            return Any
        t = types[wire]
        if t == "n":
            lo, hi = -_FINITE, _FINITE
            if wire in bounds:
                lo, hi = max(lo, -bounds[wire]), min(hi, bounds[wire])
            if kind == "state" and wire == "stop":
                lo = max(lo, 0.0)
            if wire in lims:
                lo, hi = max(lo, lims[wire][0]), min(hi, lims[wire][1])
            return Annotated[float, msgspec.Meta(ge=lo, le=hi)]
        if t in ("i", "id"):
            top = 2**53 if t == "i" else MAX_ROBOTS - 1
            if t == "id" and limits is not None:
                top = min(top, int(limits.robots) - 1)
            return Annotated[int, msgspec.Meta(ge=0, le=top)]
        if t == "b":
            return bool
        if t in ("s", "S"):
            return Annotated[str, msgspec.Meta(max_length=MAX_TEXT if t == "s" else MAX_LARGE_PAYLOAD)]
        if t == "f":
            return Annotated[list[Annotated[float, msgspec.Meta(ge=-_FINITE, le=_FINITE)]],
                             msgspec.Meta(max_length=MAX_LAW_PARAMS)]
        raise TypeError(f"no wire type for {t!r}")

    spec: list[Any] = [("v", Literal[VERSION] if typed else Any), ("kind", Literal[kind] if typed else Any)]
    for _, wire in _WIRE_NAMES[kind]:
        if wire in optional:  # absent: None when read (an explicit nil is refused: not of the type), left out written
            spec.append((wire, typ(wire) | msgspec.UnsetType, None) if typed else (wire, Any, msgspec.UNSET))
        else:
            spec.append((wire, typ(wire)))
    return msgspec.defstruct(f"Wire_{kind}", spec, forbid_unknown_fields=True, gc=False)


_FINITE = 1.7976931348623157e308  # the largest float: bounds of [-it, it] refuse inf and nan


def _wire_args(kind: str, prefix: str) -> str:
    """The arguments of a flat kind's wire struct after "v" and "kind", as source: each field `prefix + name`, a
    None optional one UNSET (left out when written)."""
    optional = _OPTIONAL.get(kind, ())
    return ", ".join(f"{prefix}{name}" if wire not in optional else f"(UNSET if {prefix}{name} is None else {prefix}{name})"
                     for name, wire in _WIRE_NAMES[kind])


def _compile_encode(kind: str) -> Callable[[Message], bytes]:
    """encode() for a flat kind: its wire struct (a None optional field left out) written by msgspec."""
    items = _wire_args(kind, "m.")
    ns: dict[str, Any] = {"W": _wire_struct(kind, typed=False), "packb": _packb, "UNSET": msgspec.UNSET}
    src = f"def enc(m):\n    return packb(W({VERSION}, {kind!r}, {items}))"
    exec(compile(src, f"<protocol encoder for {kind}>", "exec"), ns)
    enc: Callable[[Message], bytes] = ns["enc"]
    return enc


def encoder(kind: str) -> Callable[..., bytes]:
    """f(*fields) -> bytes: encode(cls(*fields)) for a flat kind, its fields given in the dataclass's order (with
    its defaults), without building the message (a robot's own state and command, every period)."""
    if kind not in _SPEC:
        raise ValueError(f"{kind!r} is not a flat message kind")
    got = _FIELD_ENCODE.get(kind)
    if got is not None:
        return got
    cls = KINDS[kind]
    declared = msgspec.structs.fields(cls)
    params = [f.name if f.required else f"{f.name}=D_{f.name}" for f in declared]
    items = _wire_args(kind, "")
    ns: dict[str, Any] = {"W": _wire_struct(kind, typed=False), "packb": _packb, "UNSET": msgspec.UNSET,
                          **{f"D_{f.name}": f.default for f in declared if not f.required}}
    src = f"def enc({', '.join(params)}):\n    return packb(W({VERSION}, {kind!r}, {items}))"
    exec(compile(src, f"<protocol field encoder for {kind}>", "exec"), ns)
    enc: Callable[..., bytes] = ns["enc"]
    _FIELD_ENCODE[kind] = enc
    return enc


_FAST_ENCODE: dict[type[Message], Callable[[Message], bytes]] = {}
_FIELD_ENCODE: dict[str, Callable[..., bytes]] = {}
_unpackb = msgpack.unpackb


class _DuplicateKey(SwarmError):
    """Raised inside msgpack's unpacking by _unique; decode() turns it into a ProtocolError."""


def _unique(pairs: list[tuple[Any, Any]]) -> dict[Any, Any]:
    """A map's pairs as a dict, refusing a key that comes twice (msgpack would keep the last silently: one reader
    would see one value and another reader the other)."""
    d = dict(pairs)
    if len(d) != len(pairs):
        raise _DuplicateKey
    return d


def _entries(payload: bytes) -> int:
    """The entry count in the header of the msgpack map `payload` starts with (-1: not a map header): a dict
    decoded from it with fewer keys had a key twice."""
    b = payload[0] if payload else 0
    if 0x80 <= b <= 0x8F:
        return b & 0x0F
    if b == 0xDE:
        return int.from_bytes(payload[1:3], "big")
    if b == 0xDF:
        return int.from_bytes(payload[1:5], "big")
    return -1


@overload
def decode(payload: bytes, kind: Literal["ref"], key_id: int | None = None, limits: Limits | None = None) -> Ref: ...
@overload
def decode(payload: bytes, kind: Literal["pose"], key_id: int | None = None, limits: Limits | None = None) -> Pose: ...
@overload
def decode(payload: bytes, kind: Literal["cmd"], key_id: int | None = None, limits: Limits | None = None) -> Cmd: ...
@overload
def decode(payload: bytes, kind: Literal["state"], key_id: int | None = None,
           limits: Limits | None = None) -> State: ...
@overload
def decode(payload: bytes, kind: Literal["status"], key_id: int | None = None,
           limits: Limits | None = None) -> Status: ...
@overload
def decode(payload: bytes, kind: Literal["obstacles"], key_id: int | None = None,
           limits: Limits | None = None) -> Obstacles: ...
@overload
def decode(payload: bytes, kind: Literal["snapshot"], key_id: int | None = None,
           limits: Limits | None = None) -> Snapshot: ...
@overload
def decode(payload: bytes, kind: Literal["clock"], key_id: int | None = None,
           limits: Limits | None = None) -> Clock: ...
@overload
def decode(payload: bytes, kind: Literal["config"], key_id: int | None = None,
           limits: Limits | None = None) -> Config: ...
@overload
def decode(payload: bytes, kind: Literal["progress"], key_id: int | None = None,
           limits: Limits | None = None) -> Progress: ...
@overload
def decode(payload: bytes, kind: Literal["run"], key_id: int | None = None, limits: Limits | None = None) -> Run: ...
@overload
def decode(payload: bytes, kind: Literal["estop"], key_id: int | None = None,
           limits: Limits | None = None) -> Estop: ...
@overload
def decode(payload: bytes, kind: Literal["bodies"], key_id: int | None = None,
           limits: Limits | None = None) -> Bodies: ...
@overload
def decode(payload: bytes, kind: Literal["claim"], key_id: int | None = None,
           limits: Limits | None = None) -> Claim: ...
@overload
def decode(payload: bytes, kind: Literal["faultstats"], key_id: int | None = None,
           limits: Limits | None = None) -> FaultStats: ...
@overload
def decode(payload: bytes, kind: Literal["event"], key_id: int | None = None,
           limits: Limits | None = None) -> Event: ...
@overload
def decode(payload: bytes, kind: Literal["proc"], key_id: int | None = None, limits: Limits | None = None) -> Proc: ...
@overload
def decode(payload: bytes, kind: str | None = None, key_id: int | None = None,
           limits: Limits | None = None) -> Message: ...


def decode(payload: bytes, kind: str | None = None, key_id: int | None = None,
           limits: Limits | None = None) -> Message:
    """Validate and decode a payload; `kind` is the expected kind, `key_id` the id in its key, `limits`
    the scenario's bounds (ids, radii, speeds, arena) on top of the physical ones. Raises only
    ProtocolError. A flat kind goes through its decoder() (limits matter to the kinds of every period only)."""
    if kind in _SPEC:
        lim = limits if kind in _HOT_BOUNDS else None
        hot = _HOT.get((kind, id(lim)))
        msg: Message = (decoder(kind, lim) if hot is None or hot[0] is not lim else hot[1])(payload, key_id)
        return msg
    return _decode_checked(payload, kind, key_id, limits)


def _decode_checked(payload: object, kind: str | None, key_id: int | None, limits: Limits | None) -> Message:
    """decode() the general way: every check in turn, with the reason of the first that fails."""
    try:
        msg: Message = _decode(payload, kind, key_id)
        if limits is not None:
            limits.check(msg)
        return msg
    except ProtocolError:
        raise
    except Exception as e:  # never anything but ProtocolError, whatever the bytes (defence in depth)
        raise ProtocolError(f"malformed payload ({type(e).__name__})") from None


def _decode(payload: object, kind: str | None, key_id: int | None) -> Any:
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise ProtocolError(f"payload must be bytes, got {type(payload).__name__}")
    limit = MAX_LARGE_PAYLOAD if kind is None or kind in LARGE_KINDS else MAX_PAYLOAD
    if len(payload) > limit:
        raise ProtocolError(f"payload of {len(payload)} bytes exceeds {limit}")
    try:
        d = _unpackb(payload, raw=False, strict_map_key=True, object_pairs_hook=_unique)
    except _DuplicateKey:
        raise ProtocolError("a map holds a key twice") from None
    except Exception as e:  # msgpack raises several types for garbage
        raise ProtocolError(f"not msgpack: {type(e).__name__}") from None
    if not isinstance(d, dict):
        raise ProtocolError(f"payload must be a map, got {type(d).__name__}")
    return _decode_map(d, kind, key_id)


def _decode_map(d: dict[str, Any], kind: str | None, key_id: int | None) -> Any:
    """The general path: every check in turn, with a reason for the first that fails."""
    msg: Any
    if type(d.get("v")) is not int or d.get("v") != VERSION:
        raise ProtocolError(f"unsupported protocol version {str(d.get('v'))[:20]} (this side speaks {VERSION})")
    k = d.get("kind")
    if not isinstance(k, str) or k not in KINDS:
        raise ProtocolError(f"unknown kind {str(k)[:40]!r}")
    if kind is not None and k != kind:
        raise ProtocolError(f"expected kind {kind!r}, got {k!r}")
    if k == "obstacles":
        msg = _obstacles(d)
    elif k == "bodies":
        msg = _bodies(d)
    elif k == "event":
        msg = _event(d)
    elif k == "snapshot":
        msg = _snapshot(d)
    else:
        spec = _SPEC[k]
        _spec_fields(d, k)
        msg = KINDS[k](**{_FIELD.get(n, n): _READ[t](d, n) for n, t in spec if n in d})
        _CHECK.get(k, lambda m: None)(msg)
    if key_id is not None and k in ("state", "config") and msg.id != key_id:
        raise ProtocolError(f"id {msg.id} in the payload does not match id {key_id} in the key")
    return msg


# --------------------------------------------------------------------------- the fast path

# A flat kind's decoder: msgspec reads the map into its wire struct, every type and bound checked as it reads
# (_wire_struct); what it refuses, or a map whose header counts more entries than it read (a key twice), goes to the
# general path (_decode_checked), which refuses it naming why. So the fast path is never more lenient, and the
# general one says what is wrong.
_HOT: dict[tuple[str, int], tuple[Limits | None, Decoder[Any]]] = {}  # (kind, id(limits)) -> (limits, decoder)


@overload
def decoder(kind: Literal["state"], limits: Limits | None = None) -> Decoder[State]: ...
@overload
def decoder(kind: Literal["pose"], limits: Limits | None = None) -> Decoder[Pose]: ...
@overload
def decoder(kind: Literal["ref"], limits: Limits | None = None) -> Decoder[Ref]: ...
@overload
def decoder(kind: Literal["cmd"], limits: Limits | None = None) -> Decoder[Cmd]: ...
@overload
def decoder(kind: str, limits: Limits | None = None) -> Decoder[HotMessage]: ...


def decoder(kind: str, limits: Limits | None = None) -> Decoder[Any]:
    """f(payload, key_id=None): decode(payload, kind, key_id, limits) for a flat kind (the kinds of every control
    period, state, pose, ref and cmd, with the scenario's `limits`), as one function made for it: msgspec reads the
    map into the kind's wire struct with every bound checked, and the message is built from it; anything it does not
    take at once goes the general way (_decode_checked), which says what is wrong. Made once per kind and Limits (a
    process has one or two; kept while they live)."""
    if kind not in _SPEC:
        raise ValueError(f"{kind!r} is not a flat message kind")
    hot = _HOT.get((kind, id(limits)))
    if hot is not None and hot[0] is limits:
        return hot[1]
    if len(_HOT) >= 64:  # limits of ended runs: let them go
        _HOT.clear()
    f = _HOT[(kind, id(limits))] = (limits, _compile_flat(kind, limits))
    return f[1]


def _compile_flat(kind: str, limits: Limits | None) -> Decoder[Any]:
    cls = KINDS[kind]
    optional = _OPTIONAL.get(kind, ())
    if limits is not None and kind in _HOT_BOUNDS and not (
            all(math.isfinite(x) for x in (limits.radius, limits.v_max, limits.w_max, *(limits.bounds or ())))
            and float(limits.robots).is_integer()):
        def general(payload: bytes, key_id: int | None = None, /) -> Any:  # an odd bound: the general path judges
            return _decode_checked(payload, kind, key_id, limits)
        return general
    required = len(_SPEC[kind]) - len(optional) + 2  # the map's entries but the optional ones ("v" and "kind" too)
    present = "".join(f" + (w.{o} is not None)" for o in optional)
    if required + len(optional) <= 15:  # a fixmap: its first byte is 0x80 + its entry count
        cond = [f"payload[0] == {0x80 + required}{present}"]
    else:
        cond = [f"entries(payload) == {required}{present}"]
    if kind == "state":
        cond.append("0.0 < w.r < w.R")
    if kind in ("state", "config"):
        cond.append("(key_id is None or w.id == key_id)")
    types = dict(_SPEC[kind])

    def value(wire: str) -> str:
        if types[wire] == "f":
            return f"tuple(w.{wire})" if wire not in optional else f"(None if w.{wire} is None else tuple(w.{wire}))"
        return f"w.{wire}"

    args = ", ".join(value(wire) for _, wire in _WIRE_NAMES[kind])
    check = kind not in _HOT_BOUNDS and kind in _CHECK  # the kinds of every period: their bounds are the struct's
    ns: dict[str, Any] = {"read": msgspec.msgpack.Decoder(_wire_struct(kind, limits)).decode, "entries": _entries,
                          "slow": _decode_checked, "cls": cls, "limits": limits, "UNSET": msgspec.UNSET,
                          "check": _CHECK.get(kind)}
    # a kind of numbers only needs no size check: msgspec stops at the first thing that is not one of its fields
    numbers = all(t in ("n", "i", "id", "b") for t in types.values())
    body = ["def dec(payload, key_id=None):",
            "    if type(payload) is not bytes:  # another buffer: the general path says what it takes",
            f"        return slow(payload, {kind!r}, key_id, limits)",
            "    try:",
            *([] if numbers else [f"        if len(payload) > {MAX_LARGE_PAYLOAD if kind in LARGE_KINDS else MAX_PAYLOAD}:",
                                  "            raise ValueError"]),
            "        w = read(payload)",
            "    except Exception:",
            f"        return slow(payload, {kind!r}, key_id, limits)",
            f"    if not ({' and '.join(cond)}):",
            f"        return slow(payload, {kind!r}, key_id, limits)",
            f"    m = cls({args})",
            *(["    check(m)"] if check else []),
            "    return m"]
    exec(compile("\n".join(body), f"<protocol decoder for {kind}>", "exec"), ns)
    dec: Decoder[Any] = ns["dec"]
    return dec

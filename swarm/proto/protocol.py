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
swarm.proto.refusals (BadMessages, Claims). This module is the codec: encode(), decode(), decoder() and the
code they generate, or take compiled from swarm/proto/_wire.c.
"""

from __future__ import annotations

import math
import os
from dataclasses import MISSING, fields
from typing import TYPE_CHECKING, overload

import msgpack
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

if TYPE_CHECKING:
    from collections.abc import Callable
    from typing import Any, Literal, Protocol, TypeVar

    from swarm.proto.messages import HotMessage, Message

try:  # the compiled wire codec of the kinds of every period (setup.py builds it where a C compiler is found)
    from swarm.proto import _wire as _wire  # re-exported: other modules read protocol._wire
    # (and tests set it, to None for the Python codec: the functions below that build codecs read it here)
except ImportError:
    _wire = None

if os.environ.get("SWARM_PURE_PYTHON"):  # the generated Python codec alone (tests compare the two)
    _wire = None

if TYPE_CHECKING:
    _M_co = TypeVar("_M_co", covariant=True)

    class Decoder(Protocol[_M_co]):
        """What decoder() returns: f(payload, key_id=None) -> the message (ProtocolError if anything is off)."""

        def __call__(self, payload: bytes, key_id: int | None = None, /) -> _M_co: ...


def _fast_init(cls: type[Any]) -> None:
    """Give a frozen dataclass an __init__ that fills its __dict__ directly (or, with __slots__, each slot
    through its descriptor): the same signature and defaults, the same object (fields, eq, hash, repr, frozen
    after it), built in a third of the time (a frozen dataclass's own __init__ calls object.__setattr__ once
    per field: about 2 us for a state, and a robot builds several messages every control period)."""
    ns: dict[str, Any] = {}
    params, stores = [], []
    slotted = "__slots__" in cls.__dict__
    for f in fields(cls):
        if f.default_factory is not MISSING:
            raise TypeError(f"{cls.__name__}.{f.name}: a default factory is not supported here")
        if f.default is MISSING:
            params.append(f.name)
        else:
            ns[f"_default_{f.name}"] = f.default
            params.append(f"{f.name}=_default_{f.name}")
        if slotted:
            ns[f"_set_{f.name}"] = cls.__dict__[f.name].__set__
            stores.append(f"    _set_{f.name}(self, {f.name})")
        else:
            stores.append(f"    d[{f.name!r}] = {f.name}")
    names = [f.name for f in fields(cls)]
    if slotted and _wire is not None:  # every slot in one compiled call (swarm/proto/_wire.c)
        ns["_fill"] = _wire.Filler(cls, tuple(names))
        stores = [f"    _fill(self, {', '.join(names)})"]
    head = "" if slotted else "    d = self.__dict__\n"
    src = f"def __init__(self, {', '.join(params)}):\n{head}" + "\n".join(stores)
    exec(compile(src, f"<protocol __init__ of {cls.__name__}>", "exec"), ns)
    ns["__init__"].__qualname__ = f"{cls.__name__}.__init__"
    cls.__init__ = ns["__init__"]


for _cls in (*KINDS.values(), Obstacle, RobotSnap, Body):
    _fast_init(_cls)


# --------------------------------------------------------------------------- encoding


def encode(msg: Any) -> bytes:
    """msgpack bytes of a message (no validation: messages are built by this process)."""
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
    else:
        for name, wire in _WIRE_NAMES[kind]:
            d[wire] = getattr(msg, name)
    payload: bytes = msgpack.packb(d, use_bin_type=True)
    return payload


# --------------------------------------------------------------------------- decoding


def _compile_fast(kind: str) -> Callable[[dict[str, Any]], Any]:
    """A decoder for the common case of a flat kind: exactly the fields of the spec, floats that are
    floats and finite, ints in range, bools. It returns the message, or None for anything else, and
    decode() then takes the general path, which accepts ints for numbers and names what is wrong.
    Generated once per kind (as dataclasses and namedtuple do): straight-line code is 3x faster than
    the general path, and a robot decodes ~10 messages per control period."""
    spec = _SPEC[kind]
    wire = {_FIELD.get(n, n): n for n, _ in spec}  # python name -> wire name
    var = {n: f"a{i}" for i, (n, _) in enumerate(spec)}
    floats = [var[n] for n, t in spec if t == "n"]
    body = ["def fast(d):",
            f"    if len(d) != {len(spec) + 2} or d.get('kind') != {kind!r} or d.get('v') != {VERSION} "
            "or type(d['v']) is not int:",
            "        return None",
            "    try:",
            *[f"        {var[n]} = d[{n!r}]" for n, _ in spec],
            "    except KeyError:",
            "        return None"]
    for n, t in spec:
        a = var[n]
        if t == "n":
            body.append(f"    if type({a}) is not float: return None")
        elif t == "b":
            body.append(f"    if type({a}) is not bool: return None")
        elif t in ("s", "S"):
            limit = MAX_TEXT if t == "s" else MAX_LARGE_PAYLOAD
            body.append(f"    if type({a}) is not str or len({a}) > {limit}: return None")
        else:
            limit = MAX_ROBOTS - 1 if t == "id" else 2**53
            body.append(f"    if type({a}) is not int or not 0 <= {a} <= {limit}: return None")
    if floats:  # finite iff their sum minus itself is 0 (inf and nan propagate; an overflow goes the long way)
        body += [f"    s = {' + '.join(floats)}", "    if s - s != 0.0: return None"]
    args = ", ".join(var[wire[f.name]] for f in fields(KINDS[kind]))
    body.append(f"    return cls({args})")
    ns: dict[str, Any] = {"cls": KINDS[kind]}
    exec(compile("\n".join(body), f"<protocol fast decoder for {kind}>", "exec"), ns)
    fast: Callable[[dict[str, Any]], Any] = ns["fast"]
    return fast


# Generated on first use of each kind (a process uses a few; compiling all at import cost ~15 ms of
# every process's start, 40 times over at `swarm up`).
_FAST: dict[str, Callable[[dict[str, Any]], Any]] = {}


def _compile_encode(kind: str) -> Callable[[Message], bytes]:
    """encode() for a flat kind as one dict display (the general loop costs 3x as much)."""
    items = ", ".join(f"{wire!r}: m.{name}" for name, wire in _WIRE_NAMES[kind])
    optional = _OPTIONAL.get(kind, ())
    src = f"def enc(m):\n    d = {{'v': {VERSION}, 'kind': {kind!r}, {items}}}\n"
    src += "".join(f"    if m.{_FIELD.get(n, n)} is None:\n        del d[{n!r}]\n" for n in optional)
    src += "    return packb(d, use_bin_type=True)"
    ns: dict[str, Any] = {"packb": msgpack.packb}
    exec(compile(src, f"<protocol fast encoder for {kind}>", "exec"), ns)
    enc: Callable[[Message], bytes] = ns["enc"]
    order = _wire_order(kind)
    if _wire is None or any(t not in ("n", "i", "id", "b") for _, t, _ in order):
        return enc
    compiled: Callable[[Message], bytes] = _wire.Encoder(kind, VERSION, order, enc, KINDS[kind])
    return compiled


def encoder(kind: str) -> Callable[..., bytes]:
    """f(*fields) -> bytes: encode(cls(*fields)) for a flat kind, its fields given in the dataclass's order,
    without building the message where the compiled codec is (a robot's own state and command, every period)."""
    if kind not in _SPEC:
        raise ValueError(f"{kind!r} is not a flat message kind")
    cls = KINDS[kind]
    fast = _FAST_ENCODE.get(cls)
    if fast is None:  # generated once, as encode() would
        fast = _FAST_ENCODE[cls] = _compile_encode(kind)
    if _wire is not None and isinstance(fast, _wire.Encoder):
        compiled: Callable[..., bytes] = fast
        return compiled
    return lambda *fields: fast(cls(*fields))


def _wire_order(kind: str) -> list[tuple[str, str, str]]:
    """A flat kind's fields as the compiled codec takes them: (wire name, _SPEC type, Python name), in the
    encoder's order (the dataclass's)."""
    types = dict(_SPEC[kind])
    return [(wire, types[wire], name) for name, wire in _WIRE_NAMES[kind]]


_FAST_ENCODE: dict[type[Message], Callable[[Message], bytes]] = {}
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
    ProtocolError. The kinds of every control period (state, pose, ref, cmd) go through decoder()."""
    if kind in _HOT_BOUNDS:
        hot = _HOT.get((kind, id(limits)))
        if hot is None or hot[0] is not limits:
            return decoder(kind, limits)(payload, key_id)
        return hot[1](payload, key_id)
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
    fast = _FAST.get(kind) if kind is not None else None
    if fast is None and kind in _SPEC:
        fast = _FAST[kind] = _compile_fast(kind)
    if fast is not None:
        msg = fast(d)
        if msg is not None:
            check = _CHECK.get(kind)
            if check is not None:
                check(msg)
            if key_id is not None and kind in ("state", "config") and msg.id != key_id:
                raise ProtocolError(f"id {msg.id} in the payload does not match id {key_id} in the key")
            return msg
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


# --------------------------------------------------------------------------- the hot path

# The kinds every robot (or the world) decodes every control period, and their bounds: spec._HOT_BOUNDS.
_ABSENT = object()  # an optional field the map leaves out (an explicit nil is a wrong type, refused)
_HOT: dict[tuple[str, int], tuple[Limits | None, Decoder[HotMessage]]] = {}  # (kind, id(limits)) -> (limits, decoder)


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


def decoder(kind: str, limits: Limits | None = None) -> Decoder[HotMessage]:
    """f(payload, key_id=None): decode(payload, kind, key_id, limits) for a kind of every control period
    (state, pose, ref, cmd), as one generated function: the payload unpacked once, every field's type,
    bound and limit checked in one expression, the message built without a dataclass __init__. It
    accepts exactly what decode() accepts of those kinds, but for numbers sent as ints: anything it does
    not accept at once goes the general way (_decode_checked), which says what is wrong, or converts.
    Generated once per kind and Limits (a process has one or two; kept while they live)."""
    hot = _HOT.get((kind, id(limits)))
    if hot is not None and hot[0] is limits:
        return hot[1]
    if len(_HOT) >= 64:  # limits of ended runs: let them go
        _HOT.clear()
    f = _HOT[(kind, id(limits))] = (limits, _compile_hot(kind, limits))
    return f[1]


def _compile_hot(kind: str, limits: Limits | None) -> Decoder[HotMessage]:
    spec = _SPEC[kind]
    cls = KINDS[kind]
    optional = _OPTIONAL.get(kind, ())
    var = {_FIELD.get(n, n): f"a{i}" for i, (n, _) in enumerate(spec)}  # python name -> local
    types = {"n": "float", "i": "int", "id": "int", "b": "bool"}
    ns: dict[str, Any] = {"unpackb": _unpackb, "entries": _entries, "slow": _decode_checked, "new": object.__new__,
                          "setattr": object.__setattr__, "cls": cls, "limits": limits, "ABSENT": _ABSENT}

    def may_lack(name: str, test: str) -> str:  # an optional field may be absent: its test then holds
        return f"({var[name]} is ABSENT or {test})" if _WIRE.get(name, name) in optional else test

    cond = [may_lack(_FIELD.get(n, n), f"type({var[_FIELD.get(n, n)]}) is {types[t]}") for n, t in spec]
    for n, t in spec:
        if t in ("i", "id"):
            cond.append(f"0 <= {var[_FIELD.get(n, n)]} <= {MAX_ROBOTS - 1 if t == 'id' else 2**53}")
    for i, (name, bound) in enumerate(_HOT_BOUNDS[kind]):
        ns[f"B{i}"] = bound
        cond.append(may_lack(name, f"-B{i} <= {var[name]} <= B{i}"))
    if kind == "state":
        cond.append(f"0 < {var['r']} < {var['R']}")
        cond.append(may_lack("stop", f"0.0 <= {var['stop']}"))
    if limits is not None:
        tol = 1 + 1e-9  # as Limits.check
        ns.update(ROBOTS=limits.robots, RADIUS=limits.radius * tol, VMAX=limits.v_max * tol,
                  WMAX=limits.w_max * tol)
        if kind == "state":
            cond += [f"{var['id']} < ROBOTS", f"{var['R']} <= RADIUS"]
        if kind == "cmd":
            cond += [f"abs({var['v']}) <= VMAX", f"abs({var['w']}) <= WMAX"]
        if limits.bounds is not None and kind in ("state", "pose"):
            ns["XMIN"], ns["XMAX"], ns["YMIN"], ns["YMAX"] = limits.bounds
            cond += [f"XMIN <= {var['x']} <= XMAX", f"YMIN <= {var['y']} <= YMAX"]
    if kind == "state":
        cond.append(f"(key_id is None or {var['id']} == key_id)")
    if "__slots__" not in cls.__dict__:
        raise TypeError(f"{cls.__name__}: a kind of every control period is a slotted dataclass")
    ns.update({f"_set_{name}": cls.__dict__[name].__set__ for name in var})
    build = ["                m = new(cls)", *[f"                _set_{name}(m, {a})" if _WIRE.get(name, name) not in optional
                                                 else f"                _set_{name}(m, None if {a} is ABSENT else {a})"
                                                 for name, a in var.items()]]
    # the map has exactly the fields of the spec, but the optional ones it leaves out: its size says how many
    size = f"{len(spec) + 2 - len(optional)}" + "".join(f" + ({o!r} in d)" for o in optional)
    body = ["def dec(payload, key_id=None):",
            f"    if type(payload) is bytes and len(payload) <= {MAX_PAYLOAD}:",
            "        try:",
            "            d = unpackb(payload, raw=False, strict_map_key=True)",
            "        except Exception:",
            f"            return slow(payload, {kind!r}, key_id, limits)",
            f"        if type(d) is dict and d.get('kind') == {kind!r} and len(d) == {size} and "
            f"type(d.get('v')) is int and d['v'] == {VERSION} and entries(payload) == len(d):",
            "            try:",
            *[f"                {var[_FIELD.get(n, n)]} = d[{n!r}]" for n, _ in spec if n not in optional],
            "            except KeyError:",
            f"                return slow(payload, {kind!r}, key_id, limits)",
            *[f"            {var[_FIELD.get(n, n)]} = d.get({n!r}, ABSENT)" for n, _ in spec if n in optional],
            "            if " + " and ".join(cond) + ":",
            *build,
            "                return m",
            f"    return slow(payload, {kind!r}, key_id, limits)"]
    exec(compile("\n".join(body), f"<protocol hot decoder for {kind}>", "exec"), ns)
    dec: Decoder[HotMessage] = ns["dec"]
    return dec if _wire is None else _compile_wire(kind, limits, dec)


def _compile_wire(kind: str, limits: Limits | None, fallback: Decoder[HotMessage]) -> Decoder[HotMessage]:
    """The compiled decoder (swarm/proto/_wire.c) of the same conditions as _compile_hot's, on the canonical
    layout only (the encoder's keys in its order, float64 numbers): anything else goes to fallback."""
    order = _wire_order(kind)
    at = {wire: i for i, (wire, _, _) in enumerate(order)}
    conds = [(_wire.IMAX, i, i, 0.0, 0.0, MAX_ROBOTS - 1 if t == "id" else 2**53)
             for i, (_, t, _) in enumerate(order) if t in ("i", "id")]

    def rng(wire: str, lo: float, hi: float) -> None:
        conds.append((_wire.RANGE, at[wire], at[wire], lo, hi, 0))

    for name, bound in _HOT_BOUNDS[kind]:
        rng(_WIRE.get(name, name), -bound, bound)
    if kind == "state":
        conds += [(_wire.GT0, at["r"], at["r"], 0.0, 0.0, 0), (_wire.LT, at["r"], at["R"], 0.0, 0.0, 0)]
        rng("stop", 0.0, MAX_COORD)
    if limits is not None:
        tol = 1 + 1e-9  # as Limits.check and _compile_hot
        if kind == "state":
            if limits.robots < 1:
                return fallback  # no id is in the scenario: the fallback says so
            conds.append((_wire.IMAX, at["id"], at["id"], 0.0, 0.0, limits.robots - 1))
            rng("R", -math.inf, limits.radius * tol)
        if kind == "cmd":  # abs(a) <= b, as a range
            rng("vel", -(limits.v_max * tol), limits.v_max * tol)
            rng("w", -(limits.w_max * tol), limits.w_max * tol)
        if limits.bounds is not None and kind in ("state", "pose"):
            xmin, xmax, ymin, ymax = limits.bounds
            rng("x", xmin, xmax)
            rng("y", ymin, ymax)
    dec: Decoder[HotMessage] = _wire.Decoder(kind, VERSION, order, conds, at["id"] if kind == "state" else -1,
                                             MAX_PAYLOAD, KINDS[kind], fallback)
    return dec

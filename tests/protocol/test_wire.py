"""The compiled wire codec (swarm/proto/_wire.c) against the generated Python one it stands in for: the same
bytes out, the same messages or the same errors in, on canonical payloads and on anything near them."""

from __future__ import annotations

import dataclasses
import math
import os

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.proto import protocol as p

# skipped without the compiled codec, except under .ci/run (SWARM_REQUIRE_COMPILED): there its absence fails
pytestmark = [pytest.mark.unit,
              pytest.mark.skipif(p._wire is None and not os.environ.get("SWARM_REQUIRE_COMPILED"),
                                 reason="the compiled codec is not built here (no C compiler)")]

FLAT = [k for k in sorted(p._SPEC) if all(t in ("n", "i", "id", "b") for _, t in p._SPEC[k])]
_LIMITS = (None, p.Limits.of(37, 1.2), p.Limits.of(5, 0.5, v_max=1.0, w_max=2.0, arena=(-3.0, 3.0, -2.0, 2.0), margin=0.5),
           p.Limits.of(0, 1.0), p.Limits(3, math.nan, math.nan, math.nan, (math.nan, 1.0, -1.0, 1.0)))


def test_ci_builds_the_compiled_codec():
    """.ci/run sets SWARM_REQUIRE_COMPILED: there a missing build (it is optional at install) is a failure."""
    if os.environ.get("SWARM_REQUIRE_COMPILED"):
        assert p._wire is not None
    assert type(p.decoder("state")).__name__ == "Decoder"
    assert type(p._compile_encode("state")).__name__ == "Encoder"


def _python(kind: str, limits):
    """The generated Python decoder of (kind, limits), as a process without the compiled codec has it."""
    wire, p._wire = p._wire, None
    try:
        return p._compile_hot(kind, limits)
    finally:
        p._wire = wire


def _python_encoder(kind: str):
    wire, p._wire = p._wire, None
    try:
        return p._compile_encode(kind)
    finally:
        p._wire = wire


def _outcome(f):
    try:
        m = f()
    except p.ProtocolError as e:
        return "ProtocolError: " + str(e)
    except (OverflowError, TypeError, ValueError) as e:
        return f"{type(e).__name__}: {e}"
    return m


_values = {
    "n": st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, 1e-320, 5e-324, 1e6,
                                                                                   1e6 + 1, 1e9, -1e9, 1.2000000013])),
    "i": st.one_of(st.integers(0, 2**64 - 1), st.sampled_from([0, 127, 128, 255, 256, 65535, 65536, 2**32 - 1, 2**32,
                                                               2**53, 2**53 + 1, 2**63, 2**64 - 1])),
    "b": st.booleans(),
}
_values["id"] = st.one_of(st.integers(0, 10), st.sampled_from([36, 37, 99_999, 100_000, 2**40]))


def _message(kind: str):
    """A message of kind with values anywhere on the wire's ranges, as the Python dict of its wire map."""
    spec = p._SPEC[kind]
    return st.fixed_dictionaries({n: _values[t] for n, t in spec})


def _payload(kind: str, fields: dict) -> bytes:
    return msgpack.packb({"v": p.VERSION, "kind": kind, **{w: fields[w] for _, w in p._WIRE_NAMES[kind]}},
                         use_bin_type=True)


@pytest.mark.parametrize("kind", [k for k in FLAT if k in p._HOT_BOUNDS])
@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_compiled_decoder_agrees_with_the_python_one(kind, data):
    """On canonical payloads with any values, and on those payloads cut short, grown or with a byte changed."""
    fields = data.draw(_message(kind))
    payload = _payload(kind, fields)
    cut = data.draw(st.one_of(st.none(), st.integers(0, len(payload) - 1)))
    if cut is not None:
        change = data.draw(st.sampled_from(["truncate", "flip", "append"]))
        if change == "truncate":
            payload = payload[:cut]
        elif change == "flip":
            payload = payload[:cut] + bytes([data.draw(st.integers(0, 255))]) + payload[cut + 1:]
        else:
            payload = payload + bytes([data.draw(st.integers(0, 255))])
    limits = data.draw(st.sampled_from(_LIMITS))
    key_id = data.draw(st.sampled_from([None, 0, 3, 4, -1, 2**70])) if kind == "state" else None
    compiled, python = p._compile_hot(kind, limits), _python(kind, limits)
    assert type(compiled).__name__ == "Decoder" or limits.robots < 1  # no id is in the scenario: Python says so
    a, b = _outcome(lambda: compiled(payload, key_id)), _outcome(lambda: python(payload, key_id))
    assert a == b
    if not isinstance(a, str):
        assert [type(getattr(a, f)) for f in type(a).__dataclass_fields__] == \
               [type(getattr(b, f)) for f in type(b).__dataclass_fields__]
        assert repr(a) == repr(b) and hash(a) == hash(b)


def test_compiled_decoder_takes_only_bytes_and_hands_the_rest_over():
    s = p.State(id=3, t=1.0, seq=5, x=1.0, y=2.0, theta=0.1, r=0.3, R=1.2, frozen=False)
    dec = p._compile_hot("state", None)
    good = p.encode(s)
    assert dec(good) == dec(good, 3) == dec(bytearray(good), 3) == dec(payload=good, key_id=3) == s
    with pytest.raises(p.ProtocolError, match="payload must be bytes"):
        dec("text", 3)
    with pytest.raises(p.ProtocolError, match="exceeds"):
        dec(good + bytes(p.MAX_PAYLOAD), 3)
    with pytest.raises(p.ProtocolError, match="does not match id 4"):
        dec(good, 4)
    with pytest.raises(TypeError):
        dec()


@pytest.mark.parametrize("kind", FLAT)
@settings(max_examples=120, deadline=None)
@given(data=st.data())
def test_compiled_encoder_writes_what_msgpack_writes(kind, data):
    """Byte for byte, for floats, ints of every width and sign, bools, float subclasses, and the types it hands
    over (None, a str, an int beyond 64 bits: msgpack's own answer or error)."""
    spec = p._SPEC[kind]
    odd = st.sampled_from([None, "x", -1, -32, -33, -128, -129, -32768, -32769, -2**31, -2**31 - 1, -2**63,
                           -2**63 - 1, 2**64, True, 3, 2.5])
    fields = data.draw(st.fixed_dictionaries({n: st.one_of(_values[t], odd) if data.draw(st.booleans()) else _values[t]
                                              for n, t in spec}))
    cls = p.KINDS[kind]
    msg = cls(**{p._FIELD.get(n, n): v for n, v in fields.items()})
    a = _outcome(lambda: p._compile_encode(kind)(msg))
    b = _outcome(lambda: _python_encoder(kind)(msg))
    assert a == b


@pytest.mark.parametrize("kind", FLAT)
@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_an_encoder_given_the_fields_writes_what_encode_writes_of_the_message(kind, data):
    """protocol.encoder(kind)(*fields): a robot's own state and command, encoded without building the message.
    The same bytes as encode(cls(*fields)), or the same error, for odd values too (handed to the fallback)."""
    spec = p._SPEC[kind]
    odd = st.sampled_from([None, "x", -1, -129, 2**64, True, 2.5])
    fields = data.draw(st.fixed_dictionaries({n: st.one_of(_values[t], odd) if data.draw(st.booleans()) else _values[t]
                                              for n, t in spec}))
    cls = p.KINDS[kind]
    msg = cls(**{p._FIELD.get(n, n): v for n, v in fields.items()})
    args = [getattr(msg, f.name) for f in dataclasses.fields(cls)]  # the dataclass's order
    assert _outcome(lambda: p.encoder(kind)(*args)) == _outcome(lambda: p.encode(msg))
    if p._wire is not None:
        assert type(p.encoder(kind)).__name__ == "Encoder"  # compiled: no message built


def test_an_encoder_given_too_few_fields_says_what_the_message_says():
    with pytest.raises(TypeError, match="missing 1 required positional argument: 'w'"):
        p.encoder("cmd")(1.0, 2, 0.5)
    with pytest.raises(ValueError, match="not a flat message kind"):
        p.encoder("obstacles")


def test_compiled_encoder_takes_float_subclasses_as_msgpack_does():
    class F(float):
        pass
    msg = p.Cmd(t=F(1.5), seq=2, v=F(-0.25), w=0.0)
    assert p._compile_encode("cmd")(msg) == _python_encoder("cmd")(msg)
    assert p.decode(p.encode(msg)) == p.Cmd(t=1.5, seq=2, v=-0.25, w=0.0)



def _slotted(name: str):
    """A fresh frozen dataclass with slots and a default, as protocol declares the messages of every period."""
    return dataclasses.make_dataclass(name, [("t", float), ("seq", int), ("x", float, 0.5)], frozen=True, slots=True)


@pytest.mark.parametrize("compiled", [True, False])
def test_a_slotted_message_is_built_as_its_dataclass_builds_it(compiled):
    """protocol._fast_init on a class with __slots__ (one compiled Filler call, or a descriptor's __set__ per
    field without the compiled codec): the same fields, defaults, equality, hash and errors as the dataclass's own
    __init__, and still frozen."""
    plain, fast = _slotted("M"), _slotted("M")
    wire, p._wire = p._wire, (p._wire if compiled else None)
    try:
        p._fast_init(fast)
    finally:
        p._wire = wire
    assert ("_fill" in fast.__init__.__globals__) == compiled
    for args, kw in (((1.0, 7), {}), ((1.0,), {"seq": 2, "x": -3.0}), ((), {"t": 0.0, "seq": 0})):
        a, b = plain(*args, **kw), fast(*args, **kw)
        assert repr(a) == repr(b) and hash(a) == hash(b) and dataclasses.astuple(a) == dataclasses.astuple(b)
        assert not hasattr(b, "__dict__")
        with pytest.raises(dataclasses.FrozenInstanceError):
            b.t = 2.0
    for bad in (lambda c: c(1.0), lambda c: c(1.0, 2, 3.0, 4), lambda c: c(1.0, 2, y=1.0)):
        with pytest.raises(TypeError) as want:
            bad(plain)
        with pytest.raises(TypeError) as got:
            bad(fast)
        assert str(got.value).split("(")[-1] == str(want.value).split("(")[-1]


def test_the_messages_of_every_period_keep_their_fields_in_slots():
    """A robot builds or decodes these every control period (a state per neighbour): slots, not a __dict__, keep
    each small (the decoder fills them through their descriptors), and the decoder's message equals the built one."""
    s = p.State(id=3, t=1.0, seq=5, x=1.0, y=2.0, theta=0.1, r=0.3, R=1.2, frozen=False)
    for m in (s, p.Pose(t=1.0, seq=5, x=1.0, y=2.0, theta=0.1), p.Ref(1.0, 5, 1.0, 2.0, 0.1, 0.5, 0.01),
              p.Cmd(1.0, 5, 0.3, -0.2), p.Status(1.0, 0.1, 0.2, 0.3, False, 4, 0, 0)):
        kind = p._KIND_OF[type(m)]
        got = p.decode(p.encode(m), kind)
        assert got == m and type(got) is type(m) and not hasattr(got, "__dict__")
    assert p._compile_hot("state", None)(p.encode(s), 3) == s
    with pytest.raises(TypeError, match="2 fields"):
        p._wire.Filler(p.Cmd, ("t", "seq"))(p.Cmd(1.0, 5, 0.3, -0.2), 1.0)
    with pytest.raises(TypeError, match="not a slot"):
        p._wire.Filler(type("Plain", (), {"x": 1.0}), ("x",))
    with pytest.raises(AttributeError):
        p._wire.Filler(p.Cmd, ("nope",))

"""The wire codec on msgspec: the bytes every flat kind's encoder writes are msgpack's (float64 numbers, the
shortest ints, the encoder's key order) for any values, the encoder of fields writes what encode() writes of the
message, and the compiled part of a period (swarm/proto/_wire.c) parses no msgpack of its own."""

from __future__ import annotations

import math
import os

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.proto import protocol as p

pytestmark = pytest.mark.unit


def test_ci_builds_the_compiled_loops_and_they_parse_no_msgpack():
    """.ci/run sets SWARM_REQUIRE_COMPILED: there a missing build (it is optional at install) is a failure. The
    codec is msgspec's and the general path's: the extension has no decoder or encoder of its own."""
    if os.environ.get("SWARM_REQUIRE_COMPILED"):
        assert p._wire is not None
    if p._wire is not None:
        assert not {"Decoder", "Encoder", "Filler"} & set(dir(p._wire))
    assert "msgspec" in type(p.decoder("state").__globals__["read"].__self__).__module__


def _outcome(f):
    try:
        return f()
    except (OverflowError, TypeError, ValueError) as e:
        return f"{type(e).__name__}"


_values = {
    "n": st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, 1e-320, 5e-324, 1e6,
                                                                                   1e6 + 1, 1e9, -1e9, 1.2000000013])),
    "i": st.one_of(st.integers(0, 2**64 - 1), st.sampled_from([0, 127, 128, 255, 256, 65535, 65536, 2**32 - 1, 2**32,
                                                               2**53, 2**53 + 1, 2**63, 2**64 - 1])),
    "b": st.booleans(),
    "s": st.text(max_size=40),
    "S": st.text(max_size=300),
    "f": st.lists(st.floats(allow_nan=False), max_size=4).map(tuple),
}
_values["id"] = st.one_of(st.integers(0, 10), st.sampled_from([36, 37, 99_999, 100_000, 2**40]))
_odd = st.sampled_from([None, "x", -1, -32, -33, -128, -129, -32768, -32769, -2**31, -2**31 - 1, -2**63, True, 3, 2.5])


def _fields(kind: str, data) -> dict:
    spec = p._SPEC[kind]
    return data.draw(st.fixed_dictionaries({n: st.one_of(_values[t], _odd) if data.draw(st.booleans()) else _values[t]
                                            for n, t in spec}))


@pytest.mark.parametrize("kind", sorted(p._SPEC))
@settings(max_examples=80, deadline=None)
@given(data=st.data())
def test_the_encoder_writes_what_msgpack_writes(kind, data):
    """Byte for byte against msgpack.packb of the wire map (the optional fields left out when None), for floats,
    ints of every width and sign, bools, strings, and odd values a message should not hold but may."""
    fields = data.draw(st.just(_fields(kind, data)))
    msg = p.KINDS[kind](**{p._FIELD.get(n, n): v for n, v in fields.items()})
    optional = p._OPTIONAL.get(kind, ())
    d = {"v": p.VERSION, "kind": kind, **{w: fields[w] for _, w in p._WIRE_NAMES[kind]
                                          if not (w in optional and fields[w] is None)}}
    assert _outcome(lambda: p.encode(msg)) == _outcome(lambda: msgpack.packb(d, use_bin_type=True))


@pytest.mark.parametrize("kind", sorted(p._SPEC))
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_an_encoder_given_the_fields_writes_what_encode_writes_of_the_message(kind, data):
    """protocol.encoder(kind)(*fields): a robot's own state and command, encoded without building the message."""
    fields = _fields(kind, data)
    cls = p.KINDS[kind]
    msg = cls(**{p._FIELD.get(n, n): v for n, v in fields.items()})
    args = [getattr(msg, f) for f in cls.__struct_fields__]  # the message's order
    assert _outcome(lambda: p.encoder(kind)(*args)) == _outcome(lambda: p.encode(msg))


def test_an_encoder_given_too_few_fields_says_what_the_message_says():
    with pytest.raises(TypeError, match="missing 1 required positional argument: 'w'"):
        p.encoder("cmd")(1.0, 2, 0.5)
    with pytest.raises(ValueError, match="not a flat message kind"):
        p.encoder("obstacles")


def test_float_and_int_subclasses_are_written_as_msgpack_writes_them():
    """numpy's float64 (a float subclass: the world's poses come from arrays) and an int subclass, as msgpack
    writes them; a type no message holds is refused as msgpack refuses it."""
    class F(float):
        pass

    class I(int):
        pass
    msg = p.Cmd(t=F(1.5), seq=I(2), v=np.float64(-0.25), w=0.0)
    assert p.encode(msg) == msgpack.packb({"v": 1, "kind": "cmd", "t": 1.5, "seq": 2, "vel": -0.25, "w": 0.0})
    assert p.decode(p.encode(msg)) == p.Cmd(t=1.5, seq=2, v=-0.25, w=0.0)
    with pytest.raises(TypeError):
        p.encode(p.Cmd(t=object(), seq=2, v=0.0, w=0.0))


def test_the_messages_are_frozen_structs_built_fast_and_equal_by_value():
    """A robot builds or decodes these every control period (a state per neighbour): frozen (a message received is
    never changed), equal and hashed by value, no __dict__, and the decoder's message equals the built one."""
    s = p.State(id=3, t=1.0, seq=5, x=1.0, y=2.0, theta=0.1, r=0.3, R=1.2, frozen=False)
    for m in (s, p.Pose(t=1.0, seq=5, x=1.0, y=2.0, theta=0.1), p.Ref(1.0, 5, 1.0, 2.0, 0.1, 0.5, 0.01),
              p.Cmd(1.0, 5, 0.3, -0.2), p.Status(1.0, 0.1, 0.2, 0.3, False, 4, 0, 0)):
        got = p.decode(p.encode(m), p.kind_of(m))
        assert got == m and hash(got) == hash(m) and type(got) is type(m) and not hasattr(got, "__dict__")
        with pytest.raises(AttributeError):
            got.t = 2.0  # type: ignore[misc]
    assert p.decoder("state")(p.encode(s), 3) == s
    assert math.isnan(p.Cmd(1.0, 5, math.nan, 0.0).v)  # a message holds what it is given: the codec checks on reading


# The C API calls that look an attribute or a method up by its name: compiled code that used one would break,
# unseen by any test of the layers, when the Python it reads renames an attribute.
BY_NAME = ("PyObject_GetAttr", "PyObject_SetAttr", "PyObject_HasAttr", "PyObject_DelAttr", "PyObject_CallMethod",
           "PyObject_VectorcallMethod", "PyObject_GetOptionalAttr", "PyObject_GenericGetAttr",
           "PyObject_GenericSetAttr", "_PyObject_GetAttrId", "_PyObject_LookupAttr", "_PyType_Lookup",
           "PyObject_Dir")


def test_no_compiled_code_reads_a_python_attribute_by_name():
    """The compiled parts (swarm/proto/_wire.c, swarm/core/_law.c) are handed what they read of Python objects:
    swarm.proto.protocol gives _wire.setup() a state's fields as a tuple, a window's take, a sample's parts and a
    payload's bytes; the state sink gets the agent's table, windows, waiting set, lock and callbacks, and the
    agent keeps its members (ended, started, posed) up to date. No C looks a name up."""
    import re
    from pathlib import Path

    root = Path(p.__file__).resolve().parents[2]
    sources = sorted([*root.glob("swarm/**/*.c"), *root.glob("swarm/**/*.h")])
    assert {s.name for s in sources} >= {"_wire.c", "_wire_states.c", "_wire_window.c", "_wire.h", "_law.c"}
    found = [f"{s.relative_to(root)}:{n}: {m.group(0)}" for s in sources
             for n, line in enumerate(s.read_text().splitlines(), 1)
             for m in re.finditer(r"\b(" + "|".join(BY_NAME) + r")\w*", line)]
    assert found == []


@pytest.mark.skipif(p._wire is None, reason="the compiled loops are not built here (no C compiler)")
def test_the_compiled_loops_read_states_through_what_setup_gave_them():
    """A state's fields reach the compiled loops only through the tuple setup()'s getter gives: a getter that
    gives something else is refused with a TypeError that says so (never a crash, never a wrong read)."""
    from operator import attrgetter, methodcaller

    from swarm.proto.window import Window
    s = p.State(id=2, t=0.02, seq=1, x=1.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False)
    table, dead, waiting = {2: s}, set(), set()
    assert p._wire.lock_bodies(table, dead, waiting, 1, 0.0, 0.0, 4.0, 0)[:4] == ([1.0], [0.0], [0.3], [1.2])
    try:
        p._wire.setup(attrgetter("id", "t", "seq"), Window.take, attrgetter("key_expr", "payload", "attachment"),
                      methodcaller("to_bytes"))
        with pytest.raises(TypeError, match=r"state_fields\(\) must give a tuple of \(id, t, seq, x, y, r, R\)"):
            p._wire.lock_bodies(table, dead, waiting, 1, 0.0, 0.0, 4.0, 0)
    finally:  # as swarm.proto.protocol sets it up
        p._wire.setup(attrgetter("id", "t", "seq", "x", "y", "r", "R"), Window.take,
                      attrgetter("key_expr", "payload", "attachment"), methodcaller("to_bytes"))
    assert p._wire.lock_bodies(table, dead, waiting, 1, 0.0, 0.0, 4.0, 0)[:4] == ([1.0], [0.0], [0.3], [1.2])

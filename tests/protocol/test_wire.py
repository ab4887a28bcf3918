"""The compiled wire codec (swarm/proto/_wire.c) against the generated Python one it stands in for: the same
bytes out, the same messages or the same errors in, on canonical payloads and on anything near them."""

from __future__ import annotations

import math
import os

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.proto import protocol as p

pytestmark = pytest.mark.skipif(p._wire is None, reason="the compiled codec is not built here (no C compiler)")

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
@settings(max_examples=400, deadline=None)
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
@settings(max_examples=300, deadline=None)
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


def test_compiled_encoder_takes_float_subclasses_as_msgpack_does():
    class F(float):
        pass
    msg = p.Cmd(t=F(1.5), seq=2, v=F(-0.25), w=0.0)
    assert p._compile_encode("cmd")(msg) == _python_encoder("cmd")(msg)
    assert p.decode(p.encode(msg)) == p.Cmd(t=1.5, seq=2, v=-0.25, w=0.0)



class _Bytes:
    def __init__(self, b: bytes) -> None:
        self.b = b

    def to_bytes(self) -> bytes:
        return self.b


class _Sample:
    """What a zenoh ring channel's try_recv() gives: key_expr, payload and attachment."""

    def __init__(self, key: str, payload: bytes, attachment: bytes | None = None) -> None:
        self.key_expr, self.payload = key, _Bytes(payload)
        self.attachment = None if attachment is None else _Bytes(attachment)


def _channel(samples: list) -> object:
    it = iter(samples)
    return lambda: next(it, None)


def _python_drain_states(channels, wake, dec, ids, states, bad, limit) -> None:
    """The same as drain_states, in Python: swarm.net.bus._ZenohInbox's drain (without the compiled
    drain), then agents.robot.Agent._take_inboxes's Python loop over the items."""
    from swarm.proto import keys

    for recv in channels:
        items = []
        while (s := recv()) is not None:
            payload = s.payload.to_bytes()
            if not payload and s.attachment is not None and s.attachment.to_bytes() == wake:
                continue
            items.append((str(s.key_expr), payload))
        for key, data in items:
            j = ids.get(key)
            if j is None:
                j = keys.cell_robot(key)
                if j is None:
                    bad.append((key, p.ProtocolError(f"not a cell key: {key!r}")))
                    continue
                if len(ids) >= limit:
                    ids.clear()
                ids[key] = j
            try:
                states.append((dec(data, j), key))
            except p.ProtocolError as e:
                bad.append((key, e))


@pytest.mark.parametrize("seed", range(8))
def test_drain_states_takes_what_the_python_loop_takes(seed):
    """A real-time robot's 9 cell inboxes drained and decoded in one compiled call (drain_states) give
    the same states, errors, key cache and order as the inboxes' Python drain and the agent's Python loop,
    over valid states, wake-ups, empty payloads, garbage, keys that are not cell keys, and a key cache at
    its limit."""
    import random

    from swarm.proto import keys

    rng = random.Random(seed)
    wake = b"swarm-inbox-wake"
    limits = p.Limits.of(37, 1.2)
    dec = p.decoder("state", limits)

    def sample():
        j = rng.randrange(40)
        key = rng.choice([f"swarm/f/cell/{rng.randrange(-2, 2)}/{rng.randrange(-2, 2)}/{j}", "swarm/f/cell/0/0/x",
                          "swarm/f/cell/0/0/007", "swarm/f/cell/0/0"])
        kind = rng.random()
        if kind < 0.5:
            s = p.State(id=j, t=rng.uniform(0, 100), seq=rng.randrange(10**6), x=rng.uniform(-50, 50),
                        y=rng.uniform(-50, 50), theta=rng.uniform(-3, 3), r=0.3, R=rng.choice([1.0, 1.2, 5.0]),
                        frozen=rng.random() < 0.2)
            return _Sample(key, p.encode(s))
        if kind < 0.6:
            return _Sample(key, b"", wake)
        if kind < 0.7:
            return _Sample(key, b"", rng.choice([None, b"other"]))
        return _Sample(key, rng.randbytes(rng.randrange(1, 40)))

    cells = [[sample() for _ in range(rng.randrange(0, 6))] for _ in range(9)]
    outs = []
    for compiled in (True, False):
        ids = {f"swarm/f/cell/0/0/{k}": k for k in range(rng.randrange(0, 6))} if not outs else dict(outs[0][3])
        ids0 = dict(ids)
        states, bad = [], []
        chans = [_channel(list(c)) for c in cells]
        if compiled:
            assert p._wire.drain_states(chans, wake, dec, ids, keys.cell_robot, states, bad, p.ProtocolError, 8) is None
        else:
            _python_drain_states(chans, wake, dec, ids, states, bad, 8)
        outs.append((states, [(k, type(e), str(e)) for k, e in bad], ids, ids0))
    (s1, b1, i1, _), (s2, b2, i2, _) = outs
    assert s1 == s2 and b1 == b2 and i1 == i2
    assert s1 or b1  # the corpus had something in it

"""The msgpack codec: round trips, a table of rejected messages, fuzzing."""

from __future__ import annotations

import math

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.proto import protocol as p

pytestmark = pytest.mark.unit

MESSAGES = [
    p.Ref(t=1.5, seq=75, x=1.0, y=-2.0, theta=0.3, v=0.5, w=0.0982),
    p.Pose(t=0.0, seq=0, x=-1e3, y=2.5, theta=-3.14),
    p.Cmd(t=2.0, seq=100, v=-0.05, w=1.2),
    p.State(id=7, t=2.0, seq=100, x=1.0, y=2.0, theta=0.1, r=0.3, R=1.2, frozen=True),
    p.Status(t=2.0, ex=0.1, ey=-0.2, etheta=0.05, frozen=False, neighbours=3, stale=1, bad=0),
    p.Obstacles(obstacles=(p.Obstacle(1.0, 2.0, 0.3, 1.2), p.Obstacle(-1.0, 0.0, 0.5, 2.0))),
    p.Obstacles(obstacles=()),
    p.Snapshot(t=3.0, seq=150, robots=(p.RobotSnap(0, 1.0, 2.0, 0.3, 0.5, 0.1, False, True),
                                        p.RobotSnap(4, 0.0, 0.0, 0.0, 0.0, 0.0, True, False))),
    p.Clock(t=1.0, seq=50, epoch=1.7e9, speed=2.0),
    p.Config(id=3, x=1.0, y=2.0, theta=0.1, dx=1.5, dy=0.0, r=0.3, R=1.2, k1=0.5, k2=0.5, k3=1.0, tu=1.0, vt=0.05,
             threshold=1, governor=True, dt=0.02, sense=1.5, reach=1.2, lockstep=True, robots=37, v_max=0.22,
             w_max=2.84, run="run-1", digest="ab" * 32),
    p.Progress(t=1.0, seq=50, duration=120.0, robots=37, alive=37, converged=3, frozen=2, min_distance=-1.0,
               misses=0, bad=0, collisions=1, overruns=0, min_obstacle=0.5, position_error=0.1, orientation_error=0.2,
               converged_at=-1.0, last_freeze=0.5, dropped=3),
    p.Run(run="20261202T024115-5f3a", digest="cd" * 32, robots=37, lockstep=True, scenario="[run]\nduration = 1.0\n"),
    p.Estop(t=1.7e9, seq=1_700_000_000_000, engaged=True, reason="a person in the arena"),
    p.Bodies(t=15.0, seq=750, bodies=(p.Body(2, 1.0, -3.0, 0.3, 1.2), p.Body(5, 0.5, 0.25, 0.3, 1.2)),
             returning=(p.Body(3, 2.0, 1.5, 0.3, 1.2),)),
    p.Bodies(t=0.0, seq=0, bodies=()),
    p.Event(t=12.0, seq=600, event="kill", robots=(5,), detail="scheduled: restart after 2 s"),
    p.Event(t=8.0, seq=400, event="partition", robots=(3, 4, 5, 6), detail="groups [0, 1, 2] | [3, 4, 5, 6]"),
    p.Claim(id=3, claim="tb3-03", granted=True, robots=7, reason=""),
    p.Proc(role="robot", id=3, host="tb3-03", pid=4242, started=1.7e9, run="20261205T030241-da6927", version="0.9.0"),
    p.FaultStats(t=15.0, seq=750, dropped_state=12, dropped_pose=3, dropped_ref=2, delayed_state=40, delayed_pose=0,
                 delayed_ref=1, max_age=0.12, frozen=True),
]


# the optional fields given (they are left out above)
WITH_OPTIONAL = [
    p.State(id=7, t=2.0, seq=100, x=1.0, y=2.0, theta=0.1, r=0.3, R=1.2, frozen=False, stop=0.125, still=2.5),
    p.Cmd(t=2.0, seq=100, v=-0.05, w=1.2, until=2.06),
    p.Pose(t=0.5, seq=25, x=1.0, y=2.0, theta=0.3, cmd=0.48),
    p.Status(t=2.0, ex=0.1, ey=-0.2, etheta=0.05, frozen=False, neighbours=3, stale=1, bad=0, held=0.25),
    p.Config(id=3, x=1.0, y=2.0, theta=0.1, dx=1.5, dy=0.0, r=0.3, R=1.2, k1=0.5, k2=0.5, k3=1.0, tu=1.0, vt=0.05,
             threshold=1, governor=True, dt=0.02, sense=1.5, reach=1.2, lockstep=True, robots=37, v_max=0.22,
             w_max=2.84, run="run-1", digest="ab" * 32, law="laws/mine.py:mine", law_sha256="0f" * 32,
             law_params=(0.5, -1.0), law_memory=4),
]

# The bytes of each message above, as docs/protocol.md has them: written by the codec before it moved onto msgspec
# (msgpack.packb of the map), so a change of the encoder that changes one byte on the wire fails here.
GOLDEN = [
    "89a17601a46b696e64a3726566a174cb3ff8000000000000a37365714ba178cb3ff0000000000000a179cbc000000000000000a57468657461cb3fd3333333333333a376656ccb3fe0000000000000a177cb3fb923a29c779a6b",
    "87a17601a46b696e64a4706f7365a174cb0000000000000000a373657100a178cbc08f400000000000a179cb4004000000000000a57468657461cbc0091eb851eb851f",
    "86a17601a46b696e64a3636d64a174cb4000000000000000a373657164a376656ccbbfa999999999999aa177cb3ff3333333333333",
    "8ba17601a46b696e64a57374617465a2696407a174cb4000000000000000a373657164a178cb3ff0000000000000a179cb4000000000000000a57468657461cb3fb999999999999aa172cb3fd3333333333333a152cb3ff3333333333333a666726f7a656ec3",
    "8aa17601a46b696e64a6737461747573a174cb4000000000000000a26578cb3fb999999999999aa26579cbbfc999999999999aa6657468657461cb3fa999999999999aa666726f7a656ec2aa6e65696768626f75727303a57374616c6501a362616400",
    "83a17601a46b696e64a96f62737461636c6573a96f62737461636c65739284a178cb3ff0000000000000a179cb4000000000000000a172cb3fd3333333333333a152cb3ff333333333333384a178cbbff0000000000000a179cb0000000000000000a172cb3fe0000000000000a152cb4000000000000000",
    "83a17601a46b696e64a96f62737461636c6573a96f62737461636c657390",
    "85a17601a46b696e64a8736e617073686f74a174cb4008000000000000a3736571cc96a6726f626f74739288a2696400a178cb3ff0000000000000a179cb4000000000000000a57468657461cb3fd3333333333333a176cb3fe0000000000000a177cb3fb999999999999aa773746f70706564c2a5616c697665c388a2696404a178cb0000000000000000a179cb0000000000000000a57468657461cb0000000000000000a176cb0000000000000000a177cb0000000000000000a773746f70706564c3a5616c697665c2",
    "86a17601a46b696e64a5636c6f636ba174cb3ff0000000000000a373657132a565706f6368cb41d954fc40000000a57370656564cb4000000000000000",
    "de0020a17601a46b696e64a6636f6e666967a2696403a178cb3ff0000000000000a179cb4000000000000000a57468657461cb3fb999999999999aa26478cb3ff8000000000000a26479cb0000000000000000a172cb3fd3333333333333a152cb3ff3333333333333a26b31cb3fe0000000000000a26b32cb3fe0000000000000a26b33cb3ff0000000000000a27475cb3ff0000000000000a27674cb3fa999999999999aa97468726573686f6c6401a8676f7665726e6f72c3a26474cb3f947ae147ae147ba573656e7365cb3ff8000000000000a57265616368cb3ff3333333333333a86c6f636b73746570c3a6726f626f747325a5765f6d6178cb3fcc28f5c28f5c29a5775f6d6178cb4006b851eb851eb8a372756ea572756e2d31a6646967657374d94061626162616261626162616261626162616261626162616261626162616261626162616261626162616261626162616261626162616261626162616261626162a56172656e61c2a4786d696ecb0000000000000000a4786d6178cb0000000000000000a4796d696ecb0000000000000000a4796d6178cb0000000000000000a7765f626f756e64cb3ff0000000000000",
    "de0017a17601a46b696e64a870726f6772657373a174cb3ff0000000000000a373657132a86475726174696f6ecb405e000000000000a6726f626f747325a5616c69766525a9636f6e76657267656403a666726f7a656e02ac6d696e5f64697374616e6365cbbff0000000000000a66d697373657300a362616400aa636f6c6c6973696f6e7301a86f76657272756e7300ac6d696e5f6f62737461636c65cb3fe0000000000000ae706f736974696f6e5f6572726f72cb3fb999999999999ab16f7269656e746174696f6e5f6572726f72cb3fc999999999999aac636f6e7665726765645f6174cbbff0000000000000ab6c6173745f667265657a65cb3fe0000000000000a764726f7070656403a468756e6700a468656c64cbbff0000000000000a8737472616e64656400",
    "87a17601a46b696e64a372756ea372756eb43230323631323032543032343131352d35663361a6646967657374d94063646364636463646364636463646364636463646364636463646364636463646364636463646364636463646364636463646364636463646364636463646364a6726f626f747325a86c6f636b73746570c3a87363656e6172696fb55b72756e5d0a6475726174696f6e203d20312e300a",
    "86a17601a46b696e64a56573746f70a174cb41d954fc40000000a3736571cf0000018bcfe56800a7656e6761676564c3a6726561736f6eb56120706572736f6e20696e20746865206172656e61",
    "86a17601a46b696e64a6626f64696573a174cb402e000000000000a3736571cd02eea6626f646965739285a2696402a178cb3ff0000000000000a179cbc008000000000000a172cb3fd3333333333333a152cb3ff333333333333385a2696405a178cb3fe0000000000000a179cb3fd0000000000000a172cb3fd3333333333333a152cb3ff3333333333333a972657475726e696e679185a2696403a178cb4000000000000000a179cb3ff8000000000000a172cb3fd3333333333333a152cb3ff3333333333333",
    "86a17601a46b696e64a6626f64696573a174cb0000000000000000a373657100a6626f6469657390a972657475726e696e6790",
    "87a17601a46b696e64a56576656e74a174cb4028000000000000a3736571cd0258a56576656e74a46b696c6ca6726f626f74739105a664657461696cbc7363686564756c65643a207265737461727420616674657220322073",
    "87a17601a46b696e64a56576656e74a174cb4020000000000000a3736571cd0190a56576656e74a9706172746974696f6ea6726f626f74739403040506a664657461696cbf67726f757073205b302c20312c20325d207c205b332c20342c20352c20365d",
    "87a17601a46b696e64a5636c61696da2696403a5636c61696da67462332d3033a76772616e746564c3a6726f626f747307a6726561736f6ea0",
    "89a17601a46b696e64a470726f63a4726f6c65a5726f626f74a2696403a4686f7374a67462332d3033a3706964cd1092a773746172746564cb41d954fc40000000a372756eb63230323631323035543033303234312d646136393237a776657273696f6ea5302e392e30",
    "8ca17601a46b696e64aa6661756c747374617473a174cb402e000000000000a3736571cd02eead64726f707065645f73746174650cac64726f707065645f706f736503ab64726f707065645f72656602ad64656c617965645f737461746528ac64656c617965645f706f736500ab64656c617965645f72656601a76d61785f616765cb3fbeb851eb851eb8a666726f7a656ec3",
    "8da17601a46b696e64a57374617465a2696407a174cb4000000000000000a373657164a178cb3ff0000000000000a179cb4000000000000000a57468657461cb3fb999999999999aa172cb3fd3333333333333a152cb3ff3333333333333a666726f7a656ec2a473746f70cb3fc0000000000000a57374696c6ccb4004000000000000",
    "87a17601a46b696e64a3636d64a174cb4000000000000000a373657164a376656ccbbfa999999999999aa177cb3ff3333333333333a5756e74696ccb40007ae147ae147b",
    "88a17601a46b696e64a4706f7365a174cb3fe0000000000000a373657119a178cb3ff0000000000000a179cb4000000000000000a57468657461cb3fd3333333333333a3636d64cb3fdeb851eb851eb8",
    "8ba17601a46b696e64a6737461747573a174cb4000000000000000a26578cb3fb999999999999aa26579cbbfc999999999999aa6657468657461cb3fa999999999999aa666726f7a656ec2aa6e65696768626f75727303a57374616c6501a362616400a468656c64cb3fd0000000000000",
    "de0024a17601a46b696e64a6636f6e666967a2696403a178cb3ff0000000000000a179cb4000000000000000a57468657461cb3fb999999999999aa26478cb3ff8000000000000a26479cb0000000000000000a172cb3fd3333333333333a152cb3ff3333333333333a26b31cb3fe0000000000000a26b32cb3fe0000000000000a26b33cb3ff0000000000000a27475cb3ff0000000000000a27674cb3fa999999999999aa97468726573686f6c6401a8676f7665726e6f72c3a26474cb3f947ae147ae147ba573656e7365cb3ff8000000000000a57265616368cb3ff3333333333333a86c6f636b73746570c3a6726f626f747325a5765f6d6178cb3fcc28f5c28f5c29a5775f6d6178cb4006b851eb851eb8a372756ea572756e2d31a6646967657374d94061626162616261626162616261626162616261626162616261626162616261626162616261626162616261626162616261626162616261626162616261626162a56172656e61c2a4786d696ecb0000000000000000a4786d6178cb0000000000000000a4796d696ecb0000000000000000a4796d6178cb0000000000000000a7765f626f756e64cb3ff0000000000000a36c6177b16c6177732f6d696e652e70793a6d696e65aa6c61775f736861323536d94030663066306630663066306630663066306630663066306630663066306630663066306630663066306630663066306630663066306630663066306630663066aa6c61775f706172616d7392cb3fe0000000000000cbbff0000000000000aa6c61775f6d656d6f727904"
]


@pytest.mark.parametrize("msg, golden", list(zip(MESSAGES + WITH_OPTIONAL, GOLDEN)),
                         ids=[type(m).__name__ for m in MESSAGES + WITH_OPTIONAL])
def test_every_kind_has_its_golden_bytes(msg, golden):
    assert len(GOLDEN) == len(MESSAGES + WITH_OPTIONAL)
    assert p.encode(msg).hex() == golden
    assert p.decode(bytes.fromhex(golden)) == msg
    kind = p.kind_of(msg)
    if kind in p._SPEC:  # the encoder given the fields, as a robot writes its own state and command
        assert p.encoder(kind)(*(getattr(msg, f) for f in type(msg).__struct_fields__)).hex() == golden


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: type(m).__name__)
def test_round_trip(msg):
    assert p.decode(p.encode(msg)) == msg


def test_every_payload_has_version_and_kind():
    for msg in MESSAGES:
        d = msgpack.unpackb(p.encode(msg))
        assert d["v"] == 1 and d["kind"] in p.KINDS


def test_snapshot_and_obstacles_are_maps_per_item():
    d = msgpack.unpackb(p.encode(next(m for m in MESSAGES if isinstance(m, p.Snapshot))))
    assert set(d["robots"][0]) == {"id", "x", "y", "theta", "v", "w", "stopped", "alive"}
    d = msgpack.unpackb(p.encode(MESSAGES[5]))
    assert set(d["obstacles"][0]) == {"x", "y", "r", "R"}


def _cmd(**changes):
    d = {"v": 1, "kind": "cmd", "t": 1.0, "seq": 3, "vel": 0.1, "w": 0.2}
    d.update(changes)
    return {k: v for k, v in d.items() if v is not _DROP}


def _state(**changes):
    d = {"v": 1, "kind": "state", "id": 4, "t": 1.0, "seq": 3, "x": 0.0, "y": 0.0, "theta": 0.0, "r": 0.3,
         "R": 1.2, "frozen": False}
    d.update(changes)
    return {k: v for k, v in d.items() if v is not _DROP}


_DROP = object()

REJECTED = [
    ("empty", b"", "not msgpack"),
    ("garbage", b"\xc1\xff\x00", "not msgpack"),
    ("truncated", msgpack.packb(_cmd())[:-3], "not msgpack"),
    ("a list", msgpack.packb([1, 2, 3]), "must be a map"),
    ("a string", msgpack.packb("cmd"), "must be a map"),
    ("no version", msgpack.packb(_cmd(v=_DROP)), "version"),
    ("version 2", msgpack.packb(_cmd(v=2)), "version"),
    ("version true", msgpack.packb(_cmd(v=True)), "version"),
    ("unknown kind", msgpack.packb(_cmd(kind="teleport")), "unknown kind"),
    ("missing field", msgpack.packb(_cmd(w=_DROP)), "missing field"),
    ("extra field", msgpack.packb(_cmd(boost=9.0)), "unknown field"),
    ("nan", msgpack.packb(_cmd(vel=math.nan)), "finite"),
    ("inf", msgpack.packb(_cmd(t=math.inf)), "finite"),
    ("string number", msgpack.packb(_cmd(vel="0.1")), "must be a number"),
    ("bool number", msgpack.packb(_cmd(vel=True)), "must be a number"),
    ("float seq", msgpack.packb(_cmd(seq=1.5)), "integer"),
    ("negative seq", msgpack.packb(_cmd(seq=-1)), "must be in"),
    ("negative id", msgpack.packb(_state(id=-1)), "must be in"),
    ("huge id", msgpack.packb(_state(id=10**9)), "must be in"),
    ("r >= R", msgpack.packb(_state(r=1.5)), "0 < r < R"),
    ("r = 0", msgpack.packb(_state(r=0.0)), "0 < r < R"),
    ("frozen not bool", msgpack.packb(_state(frozen=1)), "true or false"),
    ("int map key", msgpack.packb({1: 2}), "not msgpack"),
    ("obstacle list item", msgpack.packb({"v": 1, "kind": "obstacles", "obstacles": [[1, 2, 0.3, 1.2]]}), "map"),
    ("snapshot bad robot", msgpack.packb({"v": 1, "kind": "snapshot", "t": 0.0, "seq": 0,
                                          "robots": [{"id": 0}]}), "missing"),
    ("too large", b"\x00" * (p.MAX_LARGE_PAYLOAD + 1), "exceeds"),
    # crafted: each of these crashed a process or passed before the hardening (docs/protocol.md)
    ("unhashable kind", msgpack.packb({"v": 1, "kind": [1]}), "unknown kind"),
    ("map kind", msgpack.packb({"v": 1, "kind": {"a": 1}}), "unknown kind"),
    ("list version", msgpack.packb({"v": [1], "kind": "cmd"}), "version"),
    ("absurd speed", msgpack.packb(_cmd(vel=1.7e308)), "within"),
    ("absurd turn", msgpack.packb(_cmd(w=-101.0)), "within"),
    ("absurd time", msgpack.packb(_cmd(t=1e12)), "within"),
    ("absurd position", msgpack.packb(_state(x=2e6)), "within"),
    ("absurd radius", msgpack.packb(_state(R=1e300)), "within"),
    ("nested bomb", msgpack.packb({"v": 1, "kind": "cmd", "t": [[[[[[[[1]]]]]]]], "seq": 1, "vel": 0.1, "w": 0.0}),
     "must be a number"),
]


@pytest.mark.parametrize("name, payload, reason", REJECTED, ids=[r[0] for r in REJECTED])
def test_rejected(name, payload, reason):
    with pytest.raises(p.ProtocolError, match=reason):
        p.decode(payload)


def test_small_kinds_are_refused_past_their_size_unread():
    big = msgpack.packb(_cmd(boost="x" * (p.MAX_PAYLOAD + 10)))
    with pytest.raises(p.ProtocolError, match="exceeds"):
        p.decode(big, kind="cmd")


def test_scenario_limits():
    lim = p.Limits.of(robots=5, radius=1.2, v_max=0.22, w_max=2.84, arena=(-10.0, 10.0, -5.0, 5.0), margin=1.0)
    ok = p.encode(p.Cmd(t=1.0, seq=2, v=0.22, w=-2.84))
    assert p.decode(ok, "cmd", limits=lim).v == 0.22
    for msg, reason in ((p.Cmd(t=1.0, seq=2, v=0.3, w=0.0), "speed bounds"),
                        (p.State(id=5, t=1.0, seq=1, x=0.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False), "not in the scenario"),
                        (p.State(id=1, t=1.0, seq=1, x=0.0, y=0.0, theta=0.0, r=0.3, R=2.0, frozen=False), "largest R"),
                        (p.Pose(t=1.0, seq=1, x=11.5, y=0.0, theta=0.0), "outside the arena")):
        with pytest.raises(p.ProtocolError, match=reason):
            p.decode(p.encode(msg), limits=lim)
    assert p.decode(p.encode(p.Pose(t=1.0, seq=1, x=10.5, y=0.0, theta=0.0)), limits=lim).x == 10.5  # the margin


@settings(max_examples=120, deadline=None)
@given(st.recursive(st.one_of(st.none(), st.booleans(), st.integers(-2**63, 2**64 - 1), st.floats(), st.text(max_size=4),
                              st.binary(max_size=4)),
                    lambda inner: st.one_of(st.lists(inner, max_size=3),
                                            st.dictionaries(st.one_of(st.text(max_size=4), st.sampled_from(["v", "kind"])),
                                                            inner, max_size=3)), max_leaves=12),
       st.sampled_from([None, *p.KINDS]))
def test_fuzz_any_structure_raises_only_protocol_errors(obj, kind):
    """Any msgpack value, nested any way, for any expected kind: a message or a ProtocolError."""
    try:
        data = msgpack.packb(obj, use_bin_type=True)
    except Exception:
        return
    try:
        p.decode(data, kind)
    except p.ProtocolError:
        pass


def test_wrong_kind_for_the_key():
    with pytest.raises(p.ProtocolError, match="expected kind 'pose'"):
        p.decode(p.encode(MESSAGES[2]), kind="pose")


def test_key_id_must_match_payload_id():
    payload = p.encode(MESSAGES[3])  # id 7
    assert p.decode(payload, kind="state", key_id=7).id == 7
    with pytest.raises(p.ProtocolError, match="does not match id 8"):
        p.decode(payload, kind="state", key_id=8)


@settings(max_examples=120, deadline=None)
@given(st.binary(max_size=200))
def test_fuzz_bytes_never_crash(data):
    try:
        p.decode(data)
    except p.ProtocolError:
        pass


_scalars = st.one_of(st.none(), st.booleans(), st.integers(-2**63, 2**64 - 1), st.floats(), st.text(max_size=5),
                     st.binary(max_size=5))


@settings(max_examples=120, deadline=None)
@given(st.dictionaries(st.sampled_from(["v", "kind", "t", "seq", "vel", "w", "x", "y", "theta", "id", "r", "R",
                                        "frozen", "robots", "obstacles"]),
                       st.one_of(_scalars, st.sampled_from(list(p.KINDS)), st.lists(_scalars, max_size=3))))
def test_fuzz_structured_maps_never_crash(d):
    try:
        msg = p.decode(msgpack.packb(d, use_bin_type=True))
    except p.ProtocolError:
        return
    assert p.decode(p.encode(msg)) == msg  # anything accepted is a valid message


def test_bad_message_counter_rate_limits(caplog):
    import logging

    bad = p.BadMessages(logging.getLogger("test"), every=60.0)
    for _ in range(5):
        bad.reject("swarm/x/robot/1/cmd", p.ProtocolError("boom"))
    assert bad.count == 5
    assert len([r for r in caplog.records if "dropped a bad message" in r.getMessage()]) == 1


@pytest.mark.parametrize("change, message", [
    ({"speed": 0.0}, "'speed' must be > 0"),
    ({"epoch": -1.0}, "'epoch' must be >= 0"),
])
def test_clock_ranges(change, message):
    d = {"v": 1, "kind": "clock", "t": 0.0, "seq": 0, "epoch": 0.0, "speed": 1.0, **change}
    with pytest.raises(p.ProtocolError, match=message):
        p.decode(msgpack.packb(d))


def test_config_ranges_and_key_id():
    good = p.encode(next(m for m in MESSAGES if isinstance(m, p.Config)))
    assert p.decode(good, "config", 3).id == 3
    with pytest.raises(p.ProtocolError, match="does not match"):
        p.decode(good, "config", 4)
    d = msgpack.unpackb(good)
    for change, message in (({"threshold": 5}, "threshold"), ({"sense": 1.0}, "sense"), ({"reach": 1.0}, "reach"),
                            ({"reach": 1.5}, "reach < sense"), ({"k1": 0.0}, "k1")):
        with pytest.raises(p.ProtocolError, match=message):
            p.decode(msgpack.packb({**d, **change}))


def _near_valid(kind: str):
    """Maps that are a valid `kind` message with some fields replaced, dropped or added."""
    base = msgpack.unpackb(p.encode(next(m for m in MESSAGES if p._KIND_OF[type(m)] == kind)))
    edit = st.dictionaries(st.sampled_from(sorted(base) + ["extra"]),
                           st.one_of(_scalars, st.floats(allow_nan=True, allow_infinity=True), st.integers(-3, 3),
                                     st.sampled_from([1e308, -1e308, 0.0, 0.3, 1.2])), max_size=3)
    drop = st.sets(st.sampled_from(sorted(base)), max_size=1)
    return st.tuples(st.just(base), edit, drop)


@pytest.mark.parametrize("kind", sorted(p._SPEC))
@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_fast_decoder_agrees_with_the_general_path(kind, data):
    """The generated fast decoders accept nothing the general path refuses, and decode the same."""
    base, edit, drop = data.draw(_near_valid(kind))
    d = {k: v for k, v in {**base, **edit}.items() if k not in drop}
    try:
        fast = p.decode(msgpack.packb(d, use_bin_type=True), kind)
    except p.ProtocolError as e:
        fast = e
    try:
        slow = p._decode_map(dict(d), kind, None)
    except p.ProtocolError as e:
        slow = e
    if isinstance(slow, Exception):
        assert isinstance(fast, p.ProtocolError) and str(fast) == str(slow)
    else:
        assert fast == slow
        assert all(type(getattr(fast, f)) is type(getattr(slow, f)) for f in type(fast).__struct_fields__)


_LIMITS = (None, p.Limits.of(37, 1.2), p.Limits.of(5, 0.5, v_max=1.0, w_max=2.0, arena=(-3.0, 3.0, -2.0, 2.0), margin=0.5))


def _near_bounds(kind: str):
    """A valid `kind` message with fields replaced by values at and beyond every bound we check."""
    base = msgpack.unpackb(p.encode(next(m for m in MESSAGES if p._KIND_OF[type(m)] == kind)))
    edges = [0, 1, 4, 5, 36, 37, 2**53, 2**53 + 1, -1, True, 0.0, -0.0, 0.3, 0.5, 0.50000000049, 1.0, 1.2,
             1.2000000013, 2.0, 3.0, 3.5, 3.6, -3.5, 100.0, 100.1, 1e6, 1e6 + 1, 1e9, 1e9 + 1, -1e9,
             math.nan, math.inf, -math.inf, "x", None]
    edit = st.dictionaries(st.sampled_from(sorted(base)), st.sampled_from(edges), max_size=3)
    return st.tuples(st.just(base), edit)


@pytest.mark.parametrize("kind", sorted(p._HOT_BOUNDS))
@settings(max_examples=120, deadline=None)
@given(data=st.data())
def test_hot_decoders_agree_with_the_general_path(kind, data):
    """decoder(kind, limits) accepts what the general path accepts (or hands it over) and refuses the
    rest with the same reason: with the scenario's limits, the arena and the id in the key."""
    base, edit = data.draw(_near_bounds(kind))
    limits = data.draw(st.sampled_from(_LIMITS))
    key_id = data.draw(st.sampled_from([None, 0, 3, 4])) if kind == "state" else None
    payload = msgpack.packb({**base, **edit}, use_bin_type=True)
    outcomes = []
    for f in (lambda: p.decoder(kind, limits)(payload, key_id), lambda: p._decode_checked(payload, kind, key_id, limits)):
        try:
            outcomes.append(f())
        except p.ProtocolError as e:
            outcomes.append(str(e))
    hot, slow = outcomes
    assert hot == slow
    if not isinstance(slow, str):
        assert all(type(getattr(hot, f)) is type(getattr(slow, f)) for f in type(hot).__struct_fields__)
        assert hash(hot) == hash(slow) and repr(hot) == repr(slow)


def test_hot_decoders_refuse_what_is_not_bytes_or_too_long():
    kind = "state"
    good = p.encode(p.State(id=3, t=1.0, seq=5, x=1.0, y=2.0, theta=0.1, r=0.3, R=1.2, frozen=False))
    assert p.decoder(kind)(bytearray(good), 3) == p.decoder(kind)(good, 3)  # the general path takes other buffers
    with pytest.raises(p.ProtocolError, match="exceeds"):
        p.decoder(kind)(good + bytes(p.MAX_PAYLOAD), 3)
    with pytest.raises(p.ProtocolError, match="payload must be bytes"):
        p.decoder(kind)("text", 3)


def _map(items: list) -> bytes:
    """A msgpack map of these (key, value) pairs as given, duplicates included (msgpack.packb of a dict cannot)."""
    out = bytes([0x80 | len(items)]) if len(items) < 16 else b"\xde" + len(items).to_bytes(2, "big")
    for k, v in items:
        out += msgpack.packb(k) + (v if isinstance(v, bytes) else msgpack.packb(v))
    return out


@pytest.mark.parametrize("msg", [m for m in MESSAGES if type(m).__name__ in ("Cmd", "State", "Ref", "Pose")],
                         ids=lambda m: type(m).__name__)
def test_a_key_twice_is_refused_on_every_path(msg):
    """A map that holds a key twice is refused (docs/protocol.md: exactly the fields of its kind), first or last
    copy steering alike: msgpack keeps the last silently, and another reader may take the first. The hot decoders
    (compiled where built, and their Python twin) and the general path agree."""
    kind = next(k for k, cls in p.KINDS.items() if cls is type(msg))
    items = list(msgpack.unpackb(p.encode(msg)).items())
    key, value = items[-1]
    for payload in (_map(items + [(key, value)]), _map([(key, value)] + items)):
        with pytest.raises(p.ProtocolError, match="a map holds a key twice"):
            p.decode(payload, kind)
        with pytest.raises(p.ProtocolError, match="a map holds a key twice"):
            p.decoder(kind, None)(payload)
    assert p.decoder(kind, None)(p.encode(msg)) == msg


def test_a_key_twice_inside_a_nested_map_is_refused():
    entry = _map([("x", 1.0), ("y", 2.0), ("r", 0.3), ("R", 1.2), ("x", 50.0)])
    payload = _map([("v", 1), ("kind", "obstacles"), ("obstacles", bytes([0x91]) + entry)])
    with pytest.raises(p.ProtocolError, match="a map holds a key twice"):
        p.decode(payload, "obstacles")


def test_the_fast_path_takes_what_the_general_one_takes_of_odd_buffers_and_odd_limits():
    """Another buffer (an array) is refused as the general path refuses it; limits of floats, numpy numbers or
    infinite bounds give a message or a ProtocolError, never another exception, and leave later decoders sound."""
    import array

    import numpy as np

    s = p.State(id=3, t=1.0, seq=2, x=0.5, y=-1.0, theta=0.1, r=0.3, R=1.2, frozen=False)
    good = p.encode(s)
    with pytest.raises(p.ProtocolError, match="payload must be bytes, got array"):
        p.decode(array.array("B", good), "state", 3)
    assert p.decode(bytearray(good), "state", 3) == p.decode(memoryview(good), "state", 3) == s
    for lim in (p.Limits(10.0, 1.5), p.Limits(np.int64(10), np.float64(1.5)), p.Limits(10, math.inf),
                p.Limits(10, 1.5, -math.inf), p.Limits(10, 1.5, bounds=(math.inf, math.inf, 0.0, 1.0))):
        try:
            assert p.decode(good, "state", 3, lim) == s
        except p.ProtocolError:
            pass
    assert p.decoder("state", p.Limits(10, 1.5))(good, 3) == s


def test_a_str_subclass_is_written_as_msgpack_writes_a_str():
    import numpy as np

    run = p.Run(run=np.str_("r1"), digest="d", robots=3, lockstep=True, scenario="")
    assert p.encode(run) == msgpack.packb({"v": 1, "kind": "run", "run": "r1", "digest": "d", "robots": 3,
                                           "lockstep": True, "scenario": ""}, use_bin_type=True)

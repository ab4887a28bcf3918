"""The bus's attachments (put(..., attachment=...), subscribe_raw) and liveliness tokens on ROS 2's
`@ros2_lv` keys, on the in-memory bus and on a zenoh router on loopback."""

from __future__ import annotations

import pytest

from swarm.net import bus as busmod
from tests.ros2.helpers import Collector, wait_until

TOKEN = ("@ros2_lv/0/0a1b2c3d/0/11/MS/%/%robot1/turtlebot3_node/%robot1%cmd_vel/"
         "geometry_msgs::msg::dds_::Twist_/RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a/"
         "::,:,:,:,,")
DATA = "0/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45"


@pytest.mark.unit
def test_memory_attachment_reaches_raw_subscribers_only():
    net = busmod.MemoryNet()
    a, b = busmod.MemoryBus(net), busmod.MemoryBus(net)
    raw, plain = Collector(), Collector()
    b.subscribe_raw("0/robot1/**", raw.add)
    b.subscribe("0/robot1/**", plain.add)
    assert a.wanted(DATA)
    a.put(DATA, b"with", attachment=bytearray(b"\x01\x02"))
    a.put(DATA, b"without")
    a.put("0/robot2/cmd_vel/x/y", b"elsewhere", attachment=b"z")
    assert raw.snapshot() == [(DATA, b"with", b"\x01\x02"), (DATA, b"without", None)]
    assert plain.snapshot() == [(DATA, b"with"), (DATA, b"without")]  # a plain subscriber is unchanged
    assert all(type(p) is bytes and (att is None or type(att) is bytes) for _, p, att in raw.snapshot())


@pytest.mark.unit
def test_memory_raw_subscription_closes_and_honours_loopback():
    net = busmod.MemoryNet()
    a, b = busmod.MemoryBus(net), busmod.MemoryBus(net)
    mine, theirs = Collector(), Collector()
    sub = a.subscribe_raw(DATA, mine.add)
    b.subscribe_raw(DATA, theirs.add)
    a.put(DATA, b"remote only", loopback=False, attachment=b"x")
    assert mine.snapshot() == [] and theirs.snapshot() == [(DATA, b"remote only", b"x")]
    sub.close()
    a.put(DATA, b"again", attachment=b"y")
    assert mine.snapshot() == []
    b.close()
    assert not a.wanted(DATA)


@pytest.mark.unit
def test_memory_tokens_on_ros2_liveliness_keys():
    net = busmod.MemoryNet()
    a, b = busmod.MemoryBus(net), busmod.MemoryBus(net)
    seen = Collector()
    tok = a.token(TOKEN)
    b.watch_alive("@ros2_lv/0/**", seen.add)  # current tokens first
    other = a.token(TOKEN.replace("@ros2_lv/0/", "@ros2_lv/7/"))  # another domain: not watched
    tok.close()
    other.close()
    assert seen.snapshot() == [(TOKEN, True), (TOKEN, False)]


@pytest.mark.integration
@pytest.mark.timeout(60)
def test_zenoh_attachment_and_ros2_tokens_through_a_router(client):
    a, b = client(), client()
    raw, plain, seen = Collector(), Collector(), Collector()
    b.subscribe_raw("0/robot1/**", raw.add)
    b.subscribe("0/robot1/**", plain.add)
    b.watch_alive("@ros2_lv/0/**", seen.add)
    tok = a.token(TOKEN)
    wait_until(lambda: (TOKEN, True) in seen.snapshot(), 10, "the @ros2_lv token")
    wait_until(lambda: raw.snapshot(), 10, "a first sample through the router",
               poke=lambda: a.put(DATA, b"ping", reliable=True, attachment=b"p"))
    a.put(DATA, b"with", reliable=True, attachment=bytes(range(33)))
    a.put(DATA, b"without", reliable=True)
    wait_until(lambda: (DATA, b"without", None) in raw.snapshot(), 10, "the sample without attachment")
    got = [x for x in raw.snapshot() if x[1] != b"ping"]
    assert got == [(DATA, b"with", bytes(range(33))), (DATA, b"without", None)]
    assert [x for x in plain.snapshot() if x[1] != b"ping"] == [(DATA, b"with"), (DATA, b"without")]
    assert all(att == b"p" for _, p, att in raw.snapshot() if p == b"ping")
    tok.close()
    wait_until(lambda: (TOKEN, False) in seen.snapshot(), 10, "the token to go")

"""--id auto (world.claims): the table's rules, the world's queryable and a robot's request, on the
in-memory bus, and one claim at a time under contention (threads on a real zenoh session are in
test_fleet_processes.py)."""

from __future__ import annotations

import threading

import pytest

from swarm.core.clock import FakeClock
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import keys, protocol
from world import claims
from world.claims import ClaimServer, ClaimTable

pytestmark = pytest.mark.unit


def test_lowest_free_ids_in_order_and_the_same_key_gets_the_same_answer():
    t = ClaimTable(3)
    assert [t.claim(k, 0.0).id for k in ("a", "b", "c")] == [0, 1, 2]
    assert t.claim("b", 1.0).id == 1  # asked again (a lost reply): the same id
    c = t.claim("d", 1.0)
    assert not c.granted and "every id of the run is taken (ids 0..2" in c.reason and c.robots == 3


def test_a_claim_is_provisional_until_its_token_appears():
    t = ClaimTable(2, provisional_s=10.0)
    assert t.claim("a", 0.0).id == 0
    assert t.claim("b", 5.0).id == 1
    t.alive(1, True)  # b's robot declared its token: final
    assert t.holders() == {0: ("a", False), 1: ("b", True)}
    assert t.claim("c", 10.5).id == 0  # a's token never came within 10 s: its id is free again
    assert t.claim("c", 100.0).id == 0 and t.holders()[1] == ("b", True)  # a final claim does not lapse


def test_a_dead_robot_frees_its_id_and_its_key_gets_it_back():
    t = ClaimTable(4)
    for k in "abcd":
        t.alive(t.claim(k, 0.0).id, True)
    t.alive(2, False)  # c died (its token went away one lease later)
    t.alive(1, False)  # b too
    assert t.claim("c", 1.0).id == 2  # its own id back, though 1 is lower and free
    assert t.claim("new", 1.0).id == 1  # the freed id goes to a newcomer
    t.alive(1, True)
    t.alive(1, False)
    t.alive(2, True)
    assert t.claim("b", 2.0).id == 1  # b's last id is free again: b gets it back


def test_newcomers_prefer_ids_no_other_key_held_last():
    t = ClaimTable(4)
    for k in "ab":
        i = t.claim(k, 0.0).id
        t.alive(i, True)
        t.alive(i, False)  # a held 0, b held 1; both gone
    assert t.claim("x", 1.0).id == 2  # not 0 or 1: their keys may come back
    assert t.claim("y", 1.0).id == 3
    assert t.claim("z", 1.0).id == 0  # only the remembered ones are left: the lowest
    assert t.claim("a", 1.0).id == 1  # a's own is taken: the lowest free


def test_ids_with_a_live_token_are_taken_whoever_started_them():
    t = ClaimTable(3)
    t.alive(0, True)  # a robot started with --id 0
    t.alive(7, True)  # not in the run: ignored
    assert t.claim("a", 0.0).id == 1


def test_table_refuses_bad_arguments():
    with pytest.raises(ValueError, match="robots must be"):
        ClaimTable(0)
    with pytest.raises(ValueError, match="provisional_s"):
        ClaimTable(3, provisional_s=0.0)
    with pytest.raises(keys.KeyError_):
        ClaimTable(3).claim("a b", 0.0)


def test_claim_keys():
    assert claims.claim_key("host-3.lab") == "host-3.lab"
    a, b = claims.claim_key(None), claims.claim_key(None)
    assert a != b and keys.check_claim(a) == a
    import socket

    assert claims.claim_key(claims.HOSTNAME) == socket.gethostname()[:64]
    with pytest.raises(keys.KeyError_, match="claim key"):
        claims.claim_key("no/slash")


@pytest.fixture
def net():
    return MemoryNet()


def test_server_and_request_on_the_bus(net):
    world, clock = MemoryBus(net), FakeClock()
    server = ClaimServer(world, "f", robots=2, clock=clock)
    robot = MemoryBus(net)
    t3 = robot.token(keys.alive("f", "robot", 0))  # robot 0 was started with --id 0 before the world
    server.start()
    assert claims.request_id(robot, "f", "k1", 1.0) == 1
    assert claims.request_id(robot, "f", "k1", 1.0) == 1
    with pytest.raises(claims.ClaimRefused, match="every id of the run is taken"):
        claims.request_id(robot, "f", "k2", 1.0)
    t3.close()  # robot 0 went away: its id is free
    assert claims.request_id(robot, "f", "k2", 1.0) == 0
    assert world.query("swarm/g/world/claim/k1") == []  # another fleet's claims are not this world's
    server.close()
    with pytest.raises(claims.NoClaimAnswer, match="no answer to claim 'k3'"):
        claims.request_id(robot, "f", "k3", 0.2, retry_s=0.05)


def test_a_reply_for_another_key_or_a_bad_one_is_not_taken(net):
    robot, fake = MemoryBus(net), MemoryBus(net)
    fake.serve(keys.world_claim_any("f"), lambda key: protocol.encode(protocol.Claim(1, "other", True, 3, "")))
    with pytest.raises(claims.NoClaimAnswer, match="a reply for claim key 'other'"):
        claims.request_id(robot, "f", "mine", 0.2, retry_s=0.05)
    net2 = MemoryNet()
    robot2, liar = MemoryBus(net2), MemoryBus(net2)
    liar.serve(keys.world_claim_any("f"), lambda key: b"\x81\xa1v\x01")
    with pytest.raises(claims.NoClaimAnswer, match="bad reply"):
        claims.request_id(robot2, "f", "mine", 0.2, retry_s=0.05)


def test_concurrent_claims_never_share_an_id(net):
    """64 threads claim at once from a table of 50 ids: 50 distinct grants, 14 refusals."""
    world = MemoryBus(net)
    server = ClaimServer(world, "f", robots=50)
    server.start()
    got: list = []
    lock = threading.Lock()
    go = threading.Barrier(64)

    def one(k: int) -> None:
        bus = MemoryBus(net)
        go.wait(5.0)
        try:
            i = claims.request_id(bus, "f", f"host-{k}", 2.0)
        except claims.ClaimRefused:
            i = None
        with lock:
            got.append(i)

    threads = [threading.Thread(target=one, args=(k,)) for k in range(64)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(10.0)
    ids = [i for i in got if i is not None]
    assert len(got) == 64 and sorted(ids) == list(range(50)) and got.count(None) == 14
    assert server.table.granted == 50 and server.table.refused == 14

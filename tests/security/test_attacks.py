"""The attacks of the issue, each on the open network (no --secure: it works) and with --secure
(robot 3's identity, the strongest insider short of the world: it is stopped).

Each attack: the victim subscribes as it does in the swarm; robot 3's identity (anyone, on the
open network) primes the line by putting a message it may put and the victim hears, until the
victim hears it; then attacks; then puts a sentinel that the victim hears. Robot 3's messages
travel in order on its one link, so once the sentinel arrives, the attack has arrived or never
will. With --secure the victim has then heard nothing but robot 3's own messages; on the open
network it has been fooled.

`told`: the same with every client told of every subscription (tests/security/conftest.py: told),
so robot 3's client sends every forged message and only the router's rules can drop them; the
router's own subscriber (the auditor) then shows that none of them got in.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import pytest

from swarm.net.bus import ZenohBus
from swarm.proto import keys
from tests.security.conftest import FLEET, WAIT_S, Net, Seen, tokens_at_router

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]

PHANTOM = 500
STATUS3 = keys.robot_status(FLEET, 3)
STATE3 = keys.cell(FLEET, 0, 0, 3)


@dataclass(frozen=True)
class Attack:
    name: str
    victim: tuple[str, int]  # its identity with --secure
    listen: Callable[[ZenohBus, Seen], None]  # the victim's subscriptions (as in the swarm)
    sentinel: str  # a key robot 3 may put and the victim hears
    attack: Callable[[ZenohBus, Seen], None]  # robot 3's forgery
    forged: tuple[str, ...]  # keys (or key prefixes) of forged messages


def _listen_as_robot(bus: ZenohBus, seen: Seen) -> None:
    bus.subscribe(keys.leader_ref(FLEET), seen.add)
    bus.subscribe(keys.cell_any(FLEET, 0, 0), seen.add)  # the block around its cell


def _listen_as_world(bus: ZenohBus, seen: Seen) -> None:
    bus.watch_alive(keys.alive_any(FLEET), seen.alive)
    bus.subscribe(keys.robot_any(FLEET, "cmd"), seen.add)
    bus.subscribe(keys.robot_any(FLEET, "status"), seen.add)
    bus.subscribe(keys.cell_any(FLEET, 0, 0), seen.add)


def _forge_ref(bus: ZenohBus, seen: Seen) -> None:
    bus.put(keys.leader_ref(FLEET), b"forged: the leader is 60 m away")


def _forge_states(bus: ZenohBus, seen: Seen) -> None:
    for j in range(21):  # the 21 fake states, one per id, on the victim's cell
        if j != 3:
            bus.put(keys.cell(FLEET, 0, 0, j), f"forged state of robot {j}".encode())


def _phantom(bus: ZenohBus, seen: Seen) -> None:
    bus.token(keys.alive(FLEET, "robot", PHANTOM))
    bus.put(keys.cell(FLEET, 0, 0, PHANTOM), b"forged state of a robot that does not exist")


def _forge_cmd(bus: ZenohBus, seen: Seen) -> None:
    bus.put(keys.robot_cmd(FLEET, 5), b"forged: robot 5, full speed into the obstacle")


def _forge_config(bus: ZenohBus, seen: Seen) -> None:
    def answer(key: str) -> bytes:
        seen.add("asked the forged queryable", key.encode())
        return b"forged configuration"

    bus.serve(keys.world_config_any(FLEET), answer)


ATTACKS = [
    Attack("a forged leader reference", ("robot", 5), _listen_as_robot, STATE3, _forge_ref, (keys.leader_ref(FLEET),)),
    Attack("forged neighbour states (cell id 5 and 19 others)", ("robot", 5), _listen_as_robot, STATE3, _forge_states,
           tuple(keys.cell(FLEET, 0, 0, j) for j in range(21) if j != 3)),
    Attack("a phantom robot (token and state)", ("world", 0), _listen_as_world, STATUS3, _phantom,
           (keys.alive(FLEET, "robot", PHANTOM), keys.cell(FLEET, 0, 0, PHANTOM))),
    Attack("a forged command for robot 5", ("world", 0), _listen_as_world, STATUS3, _forge_cmd,
           (keys.robot_cmd(FLEET, 5),)),
    Attack("a second world/config queryable", ("world", 0), _listen_as_world, STATUS3, _forge_config,
           ("asked the forged queryable",)),
]


def _run(net: Net, a: Attack) -> tuple[Seen, list]:
    """Victim, prime, attack, sentinel; returns what the victim heard and robot 5's configuration
    replies (the world serves the real one)."""
    victim, heard = net.bus(*a.victim), Seen()
    a.listen(victim, heard)
    world = net.bus("world") if a.victim != ("world", 0) else victim
    world.serve(keys.world_config_any(FLEET), lambda key: b"the world's configuration")
    robot3 = net.bus("robot", 3)
    heard.retry(lambda: robot3.put(a.sentinel, b"prime"), lambda items: (a.sentinel, b"prime") in items,
                "the victim to hear robot 3")
    a.attack(robot3, heard)
    robot3.put(a.sentinel, b"sentinel")
    heard.wait_key(a.sentinel, b"sentinel")
    replies = net.bus("robot", 5).query(keys.world_config(FLEET, 5), timeout_s=WAIT_S) \
        if a.attack is _forge_config else []
    return heard, replies


def _fooled(items: list, a: Attack) -> list:
    return [it for it in items if it[0] in a.forged]


@pytest.mark.parametrize("a", ATTACKS, ids=lambda a: a.name)
def test_without_secure_the_attack_works(fleet_dir, a):
    with Net(fleet_dir, secure_=False) as net:
        heard, replies = _run(net, a)
        heard.wait_for(lambda items: _fooled(items, a), f"{a.name} to reach the victim")


@pytest.mark.parametrize("told", [False, True], ids=["generated", "told"])
@pytest.mark.parametrize("a", ATTACKS, ids=lambda a: a.name)
def test_with_secure_the_attack_is_stopped(fleet_dir, a, told):
    with Net(fleet_dir, secure_=True, told=told) as net:
        heard, replies = _run(net, a)
        assert not _fooled(heard.items, a), f"{a.name} got through: {heard.items}"
        assert [it for it in heard.items if it[0] != a.sentinel] == [], "the victim heard more than robot 3's own"
        if a.attack is _forge_config:
            assert replies == [(keys.world_config(FLEET, 5), b"the world's configuration")]
        if told:  # everything robot 3 got past the router: its own keys only
            net.auditor.wait_key(a.sentinel, b"sentinel")
            let_in = {k for k, _ in net.auditor.items}
            assert not let_in & set(a.forged), let_in
        assert keys.alive(FLEET, "robot", PHANTOM) not in tokens_at_router(net)


@pytest.mark.parametrize("secure_", [False, True], ids=["open", "secure"])
def test_robot_3s_put_on_its_own_wildcard_cell_key_reaches_no_one(fleet_dir, secure_):
    """Robot 3's certificate may put on cell/*/*/3 (the access control's rule includes that expression
    itself), and one such put would reach each of a robot's 9 cell subscriptions: zenoh's wildcard guard
    (swarm.net.bus.wildcard_guard) drops it at the router, with --secure and without."""
    with Net(fleet_dir, secure_=secure_) as net:
        victim, heard = net.bus("robot", 5), Seen()
        for cx in (-1, 0, 1):
            for cy in (-1, 0, 1):
                victim.subscribe(keys.cell_any(FLEET, cx, cy), heard.add)  # a robot's 3 x 3 block
        robot3 = net.bus("robot", 3)
        heard.retry(lambda: robot3.put(STATE3, b"prime"), lambda items: (STATE3, b"prime") in items,
                    "the victim to hear robot 3")
        for _ in range(100):
            robot3.put(f"swarm/{FLEET}/cell/*/*/3", b"wildcard")
        robot3.put(STATE3, b"sentinel")
        heard.wait_key(STATE3, b"sentinel")
        assert {p for _, p in heard.items} <= {b"prime", b"sentinel"}, heard.items

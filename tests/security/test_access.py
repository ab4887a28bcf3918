"""--secure on a real router: strangers cannot connect, and every grant of the role table works
through the generated access control (what the table allows, the router lets through)."""

from __future__ import annotations

import json
import time

import pytest
import zenoh

from swarm.net import secure
from swarm.net.bus import ZenohBus, matches, zenoh_config
from swarm.proto import keys, roles
from tests.security.conftest import FLEET, WAIT_S, Net, Seen, tokens_at_router

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]


def _no_certificate(net: Net, fleet_dir, other_dir):
    """Trusts our CA (so it could check the router), but shows no certificate of its own."""
    conf = net.config("robot", 3)
    conf.insert_json5("transport/link/tls/enable_mtls", "false")
    conf.insert_json5("transport/link/tls/connect_certificate", "null")
    conf.insert_json5("transport/link/tls/connect_private_key", "null")
    return conf


def _mtls_without_certificate(net: Net, fleet_dir, other_dir):
    conf = net.config("robot", 3)
    conf.insert_json5("transport/link/tls/connect_certificate", "null")
    conf.insert_json5("transport/link/tls/connect_private_key", "null")
    return conf


def _other_ca_certificate(net: Net, fleet_dir, other_dir):
    """Robot 3's certificate from another CA (same fleet, same common name), trusting our CA."""
    conf = net.config("robot", 3, directory=other_dir)
    conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(fleet_dir / "ca" / "ca.pem")))
    return conf


def _other_fleet_directory(net: Net, fleet_dir, other_dir):
    return net.config("robot", 3, directory=other_dir)


def _plain_tcp(net: Net, fleet_dir, other_dir):
    return zenoh_config("client", connect=[f"tcp/127.0.0.1:{net.port}"])


@pytest.mark.parametrize("make", [_no_certificate, _mtls_without_certificate, _other_ca_certificate,
                                  _other_fleet_directory, _plain_tcp], ids=lambda f: f.__name__.strip("_"))
def test_a_stranger_cannot_connect(fleet_dir, other_dir, make):
    with Net(fleet_dir, secure_=True) as net:
        conf = make(net, fleet_dir, other_dir)
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(conf).close()
        seen = Seen()
        net.bus("world").subscribe(keys.robot_any(FLEET, "status"), seen.add)
        robot3 = net.bus("robot", 3)  # the real robot 3 does connect, and is heard
        seen.retry(lambda: robot3.put(keys.robot_status(FLEET, 3), b"control"), bool, "robot 3's status")


def _concrete(expr: str) -> str:
    """A key inside `expr`: every `*` chunk (an id, a cell, a claim) becomes 3."""
    return "/".join("3" if c == "*" else c for c in expr.split("/"))


CLIENTS = [(r, 0) for r in roles.ROLES if r not in ("router", "robot")] + [("robot", 3), ("robot", 5)]


def _payload(putter: tuple[str, int], key: str, round_: int) -> bytes:
    return f"{roles.common_name(*putter)} {key} {round_}".encode()


def test_every_grant_of_the_table_works_through_the_router(fleet_dir):
    """Each identity subscribes, watches and serves all it may. Then every key it may put reaches
    every identity whose grants match it, and its publisher knows it is wanted; every query it may
    make is answered by the world; every token it may declare is seen by every watcher and held by
    the router. A second round of puts, once all is known, arrives with no retry."""
    with Net(fleet_dir, secure_=True) as net:
        buses = {c: net.bus(*c) for c in CLIENTS}
        grants = {c: roles.grants(FLEET, *c) for c in CLIENTS}
        seen = Seen()  # everything every client received: (client, key, payload)
        for c, b in buses.items():
            for e in grants[c].subscribe:
                b.subscribe(e, lambda k, p, c=c: seen.add(c, k, p))
            for e in grants[c].watch:
                b.watch_alive(e, lambda k, up, c=c: seen.add(c, k, b"up" if up else b"down"))
            for e in grants[c].serve:
                b.serve(e, lambda key: b"served by the world")
        net.router.token(keys.alive(FLEET, "router"))  # what `swarm router` declares, in the router itself
        for c, b in buses.items():
            for k in grants[c].token:
                b.token(k)
        puts = [(c, _concrete(e)) for c in CLIENTS for e in grants[c].put]
        hears = {k: [c for c in CLIENTS if any(matches(e, k) for e in grants[c].subscribe)] for _, k in puts}
        assert all(hears.values()), [k for k, h in hears.items() if not h]  # every key put is heard by someone

        def expected(round_: int) -> set:
            return {(c, k, _payload(p, k, round_)) for p, k in puts for c in hears[k]}

        tokens = [k for c in CLIENTS for k in grants[c].token] + [keys.alive(FLEET, "router")]
        watched = {(c, k, b"up") for c in CLIENTS for k in tokens if any(matches(e, k) for e in grants[c].watch)}
        seen.wait_for(lambda items: watched <= set(items), "every token at every watcher")

        def put_missing() -> None:
            got = set(seen.items)
            for p, k in puts:
                if any((c, k, _payload(p, k, 1)) not in got for c in hears[k]):
                    buses[p].put(k, _payload(p, k, 1))

        seen.retry(put_missing, lambda items: expected(1) <= set(items), "round 1 of every put", 3 * WAIT_S)
        unwanted = [(p, k) for p, k in puts if not buses[p].wanted(k)]
        assert not unwanted, f"publishers that do not know they are heard: {unwanted}"
        for p, k in puts:
            buses[p].put(k, _payload(p, k, 2))
        seen.wait_for(lambda items: expected(2) <= set(items), "round 2 of every put")
        served = sorted({k for c in CLIENTS for k in grants[c].serve if "*" not in k})  # a process's own (proc/robot/3)
        for c in CLIENTS:
            for e in grants[c].query:
                k = next((s for s in served if matches(e, s)), _concrete(e))
                assert buses[c].query(k, timeout_s=WAIT_S) == [(k, b"served by the world")], (c, k)
            if grants[c].query and any(matches(e, keys.proc(FLEET, "robot", 3)) for e in grants[c].query):
                # a wildcard query reaches each process's own queryable (swarm ps), which replies on its own key
                got = sorted(buses[c].query(keys.proc_any(FLEET), timeout_s=WAIT_S))
                assert [k for k, _ in got] == sorted(s for s in served if "/proc/" in s), (c, got)
        assert tokens_at_router(net) == set(tokens)

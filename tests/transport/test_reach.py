"""Why a client cannot reach its router, named: refused, unknown host, a port that does not speak TLS, a router of
another CA, a certificate the router refuses; and `swarm stop`/`swarm ps` say it within 5 s."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading

import pytest

from swarm.net import reach, secure
from tests.integration.helpers import free_port
from tests.security.conftest import Net

pytestmark = pytest.mark.integration

CLI = [sys.executable, "-m", "swarm.cli"]


def test_a_closed_port_and_an_unknown_host_are_named():
    assert reach.probe(f"tcp/127.0.0.1:{free_port()}") == "connection refused (no router listens there)"
    assert "host 'no-such-host.invalid' unknown" in reach.probe("tcp/no-such-host.invalid:7447")
    assert reach.probe("unixsock-stream//tmp/x") is None  # nothing to probe


def test_a_plain_tcp_port_answers_tcp_but_not_tls():
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(4)
        port = srv.getsockname()[1]
        held = []
        threading.Thread(target=lambda: held.append(srv.accept()), daemon=True).start()
        assert reach.probe(f"tcp/127.0.0.1:{port}") is None
        threading.Thread(target=lambda: held.append(srv.accept()), daemon=True).start()
        why = reach.probe(f"tls/127.0.0.1:{port}", timeout_s=0.5)
        assert why.startswith("no TLS answer within 0.5 s"), why
        for conn, _ in held:
            conn.close()


def test_a_router_of_another_ca_and_a_certificate_the_router_refuses_are_named(tmp_path):
    ours, theirs = tmp_path / "ours", tmp_path / "theirs"
    secure.init_fleet(ours, 1, "rch")
    secure.init_fleet(theirs, 1, "rch")
    with Net(ours, secure_=True) as net:
        ep = f"tls/127.0.0.1:{net.port}"

        def files(d, role="operator"):
            f = d / role
            return {"root_ca_certificate": str(f / "ca.pem"), "connect_certificate": str(f / "cert.pem"),
                    "connect_private_key": str(f / "key.pem")}

        assert reach.probe(ep, files(ours)) is None  # ours: the handshake completes, the router keeps the link
        why = reach.probe(ep, files(theirs))
        assert why.startswith("the router's certificate is not trusted"), why
        # their certificate, trusting our CA: the router refuses it
        mixed = {**files(theirs), "root_ca_certificate": files(ours)["root_ca_certificate"]}
        why = reach.probe(ep, mixed)
        assert why.startswith("the router refused this process's certificate"), why


def test_swarm_stop_and_ps_name_the_cause():
    """`swarm stop` (its deadline 5 s) and `swarm ps` (3 s) end with the cause, not zenoh's "Unable to connect"."""
    for args, cause in ((["stop", "--connect", f"tcp/127.0.0.1:{free_port()}", "--repeat-s", "0.1"],
                         "connection refused (no router listens there)"),
                        (["ps", "--connect", "tcp/no-such-host.invalid:7447"], "host 'no-such-host.invalid' unknown")):
        out = subprocess.run(CLI + args, capture_output=True, text=True, timeout=60)
        assert out.returncode == 1 and cause in out.stderr and "Unable to connect" not in out.stderr, out.stderr

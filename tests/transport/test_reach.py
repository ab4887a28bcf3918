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


def _tls_server(tmp_path, days: float, hosts: tuple[str, ...]):
    """A TLS listener on loopback with a certificate of its own CA (valid for `days`, negative: expired since),
    made for `hosts`; returns (port, the CA's PEM file, the socket to close)."""
    import datetime
    import ipaddress
    import ssl

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    now = datetime.datetime.now(datetime.timezone.utc)

    def cert(subject_key, cn, issuer_key, issuer, ca, start, end):
        b = (x509.CertificateBuilder().subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)]))
             .issuer_name(issuer).public_key(subject_key.public_key()).serial_number(x509.random_serial_number())
             .not_valid_before(start).not_valid_after(end)
             .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))
        if not ca:
            b = b.add_extension(x509.SubjectAlternativeName(
                [x509.IPAddress(ipaddress.ip_address(h)) for h in hosts]), critical=False)
        return b.sign(issuer_key, hashes.SHA256())

    ca_key, key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "test CA")])
    ca = cert(ca_key, "test CA", ca_key, ca_name, True, now - datetime.timedelta(days=30), now + datetime.timedelta(days=30))
    end = now + datetime.timedelta(days=days)
    leaf = cert(key, "router", ca_key, ca_name, False, min(now, end) - datetime.timedelta(days=2), end)
    (tmp_path / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    (tmp_path / "cert.pem").write_bytes(leaf.public_bytes(serialization.Encoding.PEM))
    (tmp_path / "key.pem").write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                         serialization.NoEncryption()))
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.load_cert_chain(tmp_path / "cert.pem", tmp_path / "key.pem")
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(4)

    def serve():
        while True:
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            try:
                ctx.wrap_socket(conn, server_side=True).close()
            except (OSError, ssl.SSLError):
                conn.close()
    threading.Thread(target=serve, daemon=True).start()
    return srv.getsockname()[1], str(tmp_path / "ca.pem"), srv


@pytest.mark.parametrize("days, hosts, said", [
    (-3, ("127.0.0.1",), "the router's certificate is not trusted: it has expired"),
    (30, ("10.9.9.9",), "the router's certificate is not trusted: it was made for another host name, not '127.0.0.1'"),
])
def test_an_expired_router_certificate_and_one_for_another_host_are_named(tmp_path, days, hosts, said):
    port, ca, srv = _tls_server(tmp_path, days, hosts)
    with srv:
        why = reach.probe(f"tls/127.0.0.1:{port}", {"root_ca_certificate": ca})
    assert why is not None and why.startswith(said), why
    other = tmp_path / "other"
    other.mkdir()
    port, _, srv = _tls_server(other, 30, ("127.0.0.1",))
    with srv:  # a router of another CA than ours
        why = reach.probe(f"tls/127.0.0.1:{port}", {"root_ca_certificate": ca})
    assert why.startswith("the router's certificate is not trusted: it is not signed by this fleet's CA"), why

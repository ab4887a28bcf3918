"""Why a zenoh client cannot reach its router: each endpoint probed the way zenoh connects (TCP, then TLS with the
identity's own files) and the cause named, for the one line a user reads.

    reach.probe("tcp/127.0.0.1:7447")   -> "connection refused (no router listens there)"
    reach.explain(conf)                  -> "tls/10.0.0.5:7447: the router refused this process's certificate ..."

zenoh itself only says "Unable to connect to any of [...]" for all of these.
"""

from __future__ import annotations

import json
import socket
import ssl

PROBE_S = 1.0  # s: each probe's own deadline (connect, handshake, the router's verdict on our certificate)


def _split(endpoint: str) -> tuple[str, str, int] | None:
    proto, _, rest = endpoint.partition("/")
    rest = rest.split("#", 1)[0].split("?", 1)[0]  # zenoh's endpoint metadata and config parts
    host, colon, port = rest.rpartition(":")
    if not colon or not port.isdigit():
        return None
    return proto, host.strip("[]"), int(port)


def probe(endpoint: str, tls: dict | None = None, timeout_s: float = PROBE_S) -> str | None:
    """None when `endpoint` answers as a router would (TCP connects; for tls/, the handshake with the files in
    `tls` (root_ca_certificate, connect_certificate, connect_private_key) completes and the router keeps the link);
    else what goes wrong, in words."""
    parts = _split(endpoint)
    if parts is None:
        return None  # not host:port (a unix socket, say): nothing to probe
    proto, host, port = parts
    if proto not in ("tcp", "tls"):
        return None
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except socket.gaierror:
        return f"host {host!r} unknown (a typo, or no name service for it here)"
    except ConnectionRefusedError:
        return "connection refused (no router listens there)"
    except (TimeoutError, socket.timeout):
        return f"no answer within {timeout_s:g} s (a firewall, or no machine at that address)"
    except OSError as e:
        return e.strerror or str(e)
    with sock:
        if proto == "tcp":
            return None
        return _tls(sock, host, tls or {}, timeout_s)


def _tls(sock, host: str, files: dict, timeout_s: float) -> str | None:
    ca, cert, key = (files.get(k) for k in ("root_ca_certificate", "connect_certificate", "connect_private_key"))
    try:
        ctx = ssl.create_default_context(cafile=ca) if ca else ssl.create_default_context()
        if cert and key:
            ctx.load_cert_chain(cert, key)
    except (OSError, ssl.SSLError) as e:
        return f"this process's TLS files cannot be read: {e}"
    try:
        with ctx.wrap_socket(sock, server_hostname=host) as tls:
            tls.settimeout(timeout_s)
            try:
                tls.recv(1)  # TLS 1.3: the router's verdict on our certificate comes after the handshake
            except (TimeoutError, socket.timeout):
                return None  # it keeps the link, waiting for zenoh's own handshake: TLS is fine
            except ssl.SSLError as e:
                return _refused(e)
            except OSError:
                return "the router closed the link after the TLS handshake (not a router of this fleet?)"
            return None
    except ssl.SSLCertVerificationError as e:
        return "the router's certificate is not trusted: " + _untrusted(e, host)
    except ssl.SSLError as e:
        return _refused(e)
    except (TimeoutError, socket.timeout):
        return f"no TLS answer within {timeout_s:g} s (is it a tls/ endpoint? a plain tcp/ router does not speak TLS)"
    except OSError as e:
        return f"the TLS handshake failed: {e.strerror or e}"


# OpenSSL's X509_V_ERR_* codes (x509_vfy.h) that name a cause a user can act on
_EXPIRED, _NOT_YET_VALID = 10, 9
_NO_ISSUER = (2, 7, 18, 19, 20, 21)  # no issuer; signed by another key (a CA of the same name); self-signed
_WRONG_NAME = (62, 64)  # hostname mismatch, IP address mismatch


def _untrusted(e: ssl.SSLCertVerificationError, host: str) -> str:
    """Why our CA file does not accept the router's certificate, in words with the fix."""
    code, why = e.verify_code, e.verify_message or str(e)
    if code == _EXPIRED:
        return f"it has expired ({why}); make the router new credentials: swarm secure init DIR --update"
    if code == _NOT_YET_VALID:
        return f"it is not valid yet ({why}): is this machine's clock right?"
    if code in _WRONG_NAME:
        return (f"it was made for another host name, not {host!r} ({why}); connect to a name it was made for, or "
                f"remake it: swarm secure init DIR --update --router-host {host}")
    if code in _NO_ISSUER:
        return (f"it is not signed by this fleet's CA ({why}): a router of another fleet directory, or this "
                "process's files come from another one")
    return (f"{why} (a router of another fleet's CA, an expired certificate, or one made for another host name: "
            "swarm secure init --router-host)")


def _refused(e: ssl.SSLError) -> str:
    reason = (e.reason or str(e)).lower()
    if "unknown_ca" in reason or "bad_certificate" in reason or "certificate_required" in reason or \
            "decrypt" in reason or "certificate" in reason:
        return (f"the router refused this process's certificate ({e.reason or e}): it is not of the router's CA "
                "(another fleet's directory?), expired, or revoked")
    return f"the TLS handshake failed: {e.reason or e}"


def explain(conf) -> str | None:
    """The cause for the first endpoint of zenoh config `conf`'s connect list that does not answer; None if each
    answers (then zenoh's own error is the cause: a session limit, an access rule)."""
    try:
        endpoints = json.loads(conf.get_json("connect/endpoints"))
    except Exception:
        return None
    if isinstance(endpoints, dict):  # zenoh's per-mode form
        endpoints = endpoints.get("client") or next(iter(endpoints.values()), [])
    files = {}
    for name in ("root_ca_certificate", "connect_certificate", "connect_private_key"):
        try:
            value = json.loads(conf.get_json(f"transport/link/tls/{name}"))
        except Exception:
            value = None
        if isinstance(value, str):
            files[name] = value
    for ep in endpoints if isinstance(endpoints, list) else []:
        if not isinstance(ep, str):
            continue
        why = probe(ep, files)
        if why is not None:
            return f"{ep}: {why}"
    return None

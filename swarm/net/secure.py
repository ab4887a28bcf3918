"""`--secure`: a certificate per process, mutual TLS to the router, and the router's access control
generated from the role table (swarm.proto.roles). docs/security.md is the user's guide.

    init_fleet(dir, robots=7, fleet="default", router_hosts=("hub.lan",), port=7447)   # swarm secure init
    ident = find_identity(dir, "robot", 3)   # DIR/robot-3, or DIR itself when it is that identity's folder
    conf = secure_config(dir, "robot", 3)    # zenoh.Config: an mTLS client of the router, file paths absolute
    conf = router_config(dir)                # the router: mTLS listener + access_control (default deny)
    robot_id_of(dir)                         # the robot id in a folder's certificate (None: not a robot's)

What init_fleet writes (one folder per identity, so a robot's machine gets its own folder and
nothing else; a folder's zenoh.json5 names its files relative to the folder):

    DIR/fleet.json              fleet, robots, port, router hosts, extra robot keys, revoked ids
    DIR/ca/ca.pem, ca-key.pem   the certificate authority (its key signs new robots: keep it offline)
    DIR/router/                 ca.pem, cert.pem, key.pem (server + client certificate), zenoh.json5 (with the ACL)
    DIR/<role>/                 ca.pem, cert.pem, key.pem, zenoh.json5 for launcher, world, leader, viz,
                                recorder, operator
    DIR/robot-<i>/              the same for robot i

A certificate's common name is its identity (swarm.proto.roles.common_name: "world", "robot-3"), and
its organizational unit the fleet; the router's rules name common names, so what a process may do is
what its certificate says, whatever flags it was started with.

Zenoh's access control, as this module uses it (checked by tests/security with eclipse-zenoh 1.10):
the router checks every message from a client (ingress) and to a client (egress) against the rules
of that client's subject; a rule's key expression must include the message's (a subscription to
`a/*` is not allowed by a rule on `a/1`); under default deny the declarations need rules too.
ACTION_MESSAGES is what each action of the role table needs.
"""

from __future__ import annotations

import datetime
import ipaddress
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from swarm.proto import keys, roles
from swarm.core.errors import SwarmError

CA_DAYS = 3650  # the authority: ten years (a new CA re-issues everything: docs/security.md)
CERT_DAYS = 825  # a process's certificate: about two years (the longest browsers accept for servers)
DEFAULT_PORT = 7447
CONFIG = "zenoh.json5"
CERT, KEY, CA = "cert.pem", "key.pem", "ca.pem"
MANIFEST = "fleet.json"
LOCAL_HOSTS = ("127.0.0.1", "localhost")  # the router's certificate always names these

# The zenoh ACL messages (and their flow, seen from the router) that each action of the role table
# needs; the key expressions are the action's grants (swarm.proto.roles.Grants).
ACTION_MESSAGES: dict[str, tuple[tuple[str, str], ...]] = {
    "put": (("put", "ingress"),),
    # a publisher learns who subscribes to what it puts: bus.wanted() asks zenoh that
    "listeners": (("declare_subscriber", "egress"),),
    "subscribe": (("declare_subscriber", "ingress"), ("put", "egress")),
    "serve": (("declare_queryable", "ingress"), ("reply", "ingress")),
    # a queryable is asked on the keys it serves, every id (a wildcard query reaches it; it replies on its own)
    "askers": (("query", "egress"),),
    "query": (("query", "ingress"), ("reply", "egress")),
    "token": (("liveliness_token", "ingress"),),
    # the router sends the tokens as declarations (a subscriber's history too); liveliness().get()
    # is a liveliness query
    "watch": (("declare_liveliness_subscriber", "ingress"), ("liveliness_query", "ingress"),
              ("liveliness_token", "egress")),
}
ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable", "liveliness_token",
                "liveliness_query", "declare_liveliness_subscriber")


class SecureError(SwarmError, ValueError):
    """A --secure directory that cannot serve: missing, not made by `swarm secure init`, or the
    wrong identity (the message says which and what to do)."""


@dataclass(frozen=True)
class Identity:
    """One process's credentials: its folder and what its certificate says."""

    folder: Path
    role: str
    id: int
    fleet: str
    common_name: str
    not_after: datetime.datetime

    @property
    def config(self) -> Path:
        return self.folder / CONFIG


# --------------------------------------------------------------------------- certificates


def _key():
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _name(cn: str, fleet: str):
    from cryptography.x509 import Name, NameAttribute
    from cryptography.x509.oid import NameOID

    return Name([NameAttribute(NameOID.ORGANIZATION_NAME, "swarm"),
                 NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, fleet),
                 NameAttribute(NameOID.COMMON_NAME, cn)])


def _san(host: str):
    from cryptography import x509

    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def _certificate(subject_key, subject, issuer_key, issuer, days: int, ca: bool, hosts: tuple[str, ...] = (),
                 client: bool = True):
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.x509.oid import ExtendedKeyUsageOID

    now = datetime.datetime.now(datetime.timezone.utc)
    b = (x509.CertificateBuilder().subject_name(subject).issuer_name(issuer)
         .public_key(subject_key.public_key()).serial_number(x509.random_serial_number())
         .not_valid_before(now - datetime.timedelta(hours=1))  # a little clock skew between machines
         .not_valid_after(now + datetime.timedelta(days=days))
         .add_extension(x509.BasicConstraints(ca=ca, path_length=0 if ca else None), critical=True)
         .add_extension(x509.SubjectKeyIdentifier.from_public_key(subject_key.public_key()), critical=False)
         .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(issuer_key.public_key()), critical=False))
    if ca:
        b = b.add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                          data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                          crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
    else:
        b = b.add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                          data_encipherment=False, key_agreement=False, key_cert_sign=False,
                                          crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
        usages = ([ExtendedKeyUsageOID.SERVER_AUTH] if hosts else []) + ([ExtendedKeyUsageOID.CLIENT_AUTH] if client else [])
        b = b.add_extension(x509.ExtendedKeyUsage(usages), critical=False)
        if hosts:
            b = b.add_extension(x509.SubjectAlternativeName([_san(h) for h in hosts]), critical=False)
    return b.sign(issuer_key, hashes.SHA256())


def _pem_cert(cert) -> bytes:
    from cryptography.hazmat.primitives.serialization import Encoding

    return cert.public_bytes(Encoding.PEM)


def _pem_key(key) -> bytes:
    from cryptography.hazmat.primitives.serialization import Encoding, NoEncryption, PrivateFormat

    return key.private_bytes(Encoding.PEM, PrivateFormat.PKCS8, NoEncryption())


def _write(path: Path, data: bytes, secret: bool = False) -> None:
    tmp = path.with_name(path.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if secret else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    tmp.replace(path)


def _load_cert(path: Path):
    from cryptography import x509

    try:
        return x509.load_pem_x509_certificate(path.read_bytes())
    except (OSError, ValueError) as e:
        raise SecureError(f"{path}: not a readable PEM certificate ({e})") from None


def _load_key(path: Path):
    from cryptography.hazmat.primitives.serialization import load_pem_private_key

    try:
        return load_pem_private_key(path.read_bytes(), password=None)
    except (OSError, ValueError, TypeError) as e:
        raise SecureError(f"{path}: not a readable unencrypted PEM private key ({e})") from None


def _subject_field(cert, oid) -> str | None:
    attrs = cert.subject.get_attributes_for_oid(oid)
    return str(attrs[0].value) if attrs else None


# --------------------------------------------------------------------------- identities


def identity_of(folder: str | os.PathLike) -> Identity:
    """The identity whose folder this is, read from its certificate (the router trusts nothing else)."""
    from cryptography.x509.oid import NameOID

    folder = Path(folder)
    cert = _load_cert(folder / CERT)
    cn = _subject_field(cert, NameOID.COMMON_NAME) or ""
    parsed = roles.parse_common_name(cn)
    fleet = _subject_field(cert, NameOID.ORGANIZATIONAL_UNIT_NAME) or ""
    if parsed is None or not fleet:
        raise SecureError(f"{folder / CERT}: common name {cn!r} / fleet {fleet!r} is not a swarm identity")
    return Identity(folder, parsed[0], parsed[1], fleet, cn, cert.not_valid_after_utc)


def robot_id_of(folder: str | os.PathLike) -> int | None:
    """The robot id in a folder's certificate; None when the folder is not a robot's."""
    ident = identity_of(folder)
    return ident.id if ident.role == "robot" else None


def find_identity(directory: str | os.PathLike, role: str, robot_id: int | None = None) -> Identity:
    """The identity `role` (robot `robot_id`) in `directory`: either a fleet directory made by
    init_fleet (its sub-folder is used) or one identity's folder (copied to a robot's machine). A
    folder of another role, or of a robot whose id is not `robot_id`, is refused: a robot's id is its
    certificate's."""
    d = Path(directory)
    if role not in roles.ROLES:
        raise SecureError(f"no role {role!r} (roles: {', '.join(roles.ROLES)})")
    if (d / CERT).is_file():
        ident = identity_of(d)
        if ident.role != role:
            raise SecureError(f"{d} holds the certificate of {ident.common_name}, not of a {role}")
        if role == "robot" and robot_id is not None and ident.id != robot_id:
            raise SecureError(f"{d} holds the certificate of {ident.common_name}: its id is {ident.id}, "
                              f"not {robot_id} (a robot's id is its certificate's)")
    elif (d / MANIFEST).is_file():
        if role == "robot" and robot_id is None:
            raise SecureError(f"{d} is a fleet directory: a robot needs its id to find its folder")
        sub = d / roles.common_name(role, robot_id or 0)
        if not (sub / CERT).is_file():
            m = read_manifest(d)
            why = " (revoked)" if role == "robot" and robot_id in m.get("revoked", []) else ""
            raise SecureError(f"{d} has no credentials for {roles.common_name(role, robot_id or 0)}{why}; "
                              f"it was made for robots 0..{m.get('robots', 0) - 1}")
        ident = find_identity(sub, role, robot_id)
    elif not d.exists():
        raise SecureError(f"{d}: no such directory (make one with: swarm secure init {d} --robots N)")
    else:
        raise SecureError(f"{d}: neither a fleet directory of `swarm secure init` ({MANIFEST}) "
                          f"nor an identity's folder ({CERT})")
    for name in (KEY, CA, CONFIG):
        if not (ident.folder / name).is_file():
            raise SecureError(f"{ident.folder}: {name} is missing")
    return ident


def read_manifest(directory: str | os.PathLike) -> dict:
    path = Path(directory) / MANIFEST
    try:
        m = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise SecureError(f"{path}: cannot read it ({e})") from None
    if not isinstance(m, dict) or not isinstance(m.get("fleet"), str) or not isinstance(m.get("robots"), int):
        raise SecureError(f"{path}: not a manifest of `swarm secure init`")
    return m


# --------------------------------------------------------------------------- configs and the ACL


def endpoint(host: str, port: int) -> str:
    """A TLS endpoint (IPv6 addresses in brackets)."""
    try:
        if ipaddress.ip_address(host).version == 6:
            host = f"[{host}]"
    except ValueError:
        pass
    return f"tls/{host}:{int(port)}"


def access_control(fleet: str, robots: int, extra_robot_keys: tuple[str, ...] = (),
                   revoked: tuple[int, ...] = ()) -> dict:
    """The router's access_control block: default deny; per identity a subject (its certificate's
    common name), the rules of its grants (swarm.proto.roles.grants, messages per ACTION_MESSAGES)
    and a policy joining them. Other routers (common name "router") may route everything of the fleet.
    Revoked robots get no allow rule and an explicit deny of everything."""
    rules, subjects, policies = [], [], []
    for role, i in roles.identities(robots):
        if role == "robot" and i in revoked:
            continue
        cn = roles.common_name(role, i)
        g = roles.grants(fleet, role, i, extra_robot_keys if role == "robot" else ())
        by_flow: dict[tuple[str, tuple[str, ...]], set[str]] = {}
        for action in ACTION_MESSAGES:
            exprs = g.of(action)
            if not exprs:
                continue
            for message, flow in ACTION_MESSAGES[action]:
                by_flow.setdefault((flow, tuple(exprs)), set()).add(message)
        ids = []
        for n, ((flow, exprs), messages) in enumerate(sorted(by_flow.items())):
            rid = f"{cn}/{n}"
            rules.append({"id": rid, "permission": "allow", "flows": [flow],
                          "messages": sorted(messages), "key_exprs": list(exprs)})
            ids.append(rid)
        if role == "router":  # another router's link: it routes the fleet's traffic both ways
            rules.append({"id": "router/route", "permission": "allow", "flows": ["ingress", "egress"],
                          "messages": list(ALL_MESSAGES), "key_exprs": [f"{keys.base(fleet)}/**"]})
            ids.append("router/route")
        subjects.append({"id": cn, "cert_common_names": [cn]})
        if ids:
            policies.append({"id": cn, "rules": ids, "subjects": [cn]})
    if revoked:  # default deny already refuses them everything; this says so, and wins over any allow
        # ("**" does not match chunks that start with "@", such as ROS 2's @ros2_lv: their extra keys too)
        extra = sorted({roles.extra_expression(t, i) for t in extra_robot_keys for i in revoked})
        rules.append({"id": "revoked", "permission": "deny", "flows": ["ingress", "egress"],
                      "messages": list(ALL_MESSAGES), "key_exprs": ["**", *extra]})
        subjects.append({"id": "revoked", "cert_common_names": [roles.common_name("robot", i) for i in sorted(revoked)]})
        policies.append({"id": "revoked", "rules": ["revoked"], "subjects": ["revoked"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def _client_doc(connect: list[str]) -> dict:
    return {
        "mode": "client",
        "connect": {"endpoints": connect},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"protocols": ["tls"], "tls": {
            "root_ca_certificate": CA, "connect_certificate": CERT, "connect_private_key": KEY,
            "enable_mtls": True, "verify_name_on_connect": True, "close_link_on_expiration": True}}},
    }


def _router_doc(listen: list[str], acl: dict) -> dict:
    return {
        "mode": "router",
        "listen": {"endpoints": listen},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"protocols": ["tls"], "tls": {
            "root_ca_certificate": CA, "listen_certificate": CERT, "listen_private_key": KEY,
            "connect_certificate": CERT, "connect_private_key": KEY,
            "enable_mtls": True, "verify_name_on_connect": True, "close_link_on_expiration": True}}},
        "access_control": acl,
    }


TLS_FILES = ("root_ca_certificate", "listen_certificate", "listen_private_key", "connect_certificate",
             "connect_private_key")


def _check_tls_endpoints(flag: str, eps: list[str] | None) -> None:
    for ep in eps or []:
        if not isinstance(ep, str) or not ep.startswith("tls/"):
            raise SecureError(f"{flag} {ep!r}: with --secure every endpoint is tls/HOST:PORT")


def secure_config(directory: str | os.PathLike, role: str, robot_id: int | None = None,
                  connect: list[str] | None = None, listen: list[str] | None = None):
    """The zenoh.Config of identity `role` (robot `robot_id`) from `directory` (see find_identity):
    its folder's zenoh.json5 with the certificate files made absolute; `connect` / `listen` (tls/
    endpoints) replace the file's. The router's (role "router") carries the access control."""
    import zenoh

    ident = find_identity(directory, role, robot_id)
    _check_tls_endpoints("--connect", connect)
    _check_tls_endpoints("--listen", listen)
    try:
        conf = zenoh.Config.from_file(str(ident.config))
    except Exception as e:
        raise SecureError(f"{ident.config}: {e}") from None
    for name in TLS_FILES:
        path = f"transport/link/tls/{name}"
        value = json.loads(conf.get_json(path))
        if isinstance(value, str) and not os.path.isabs(value):
            conf.insert_json5(path, json.dumps(str((ident.folder / value).absolute())))
    if connect is not None:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if listen is not None:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return conf


def router_config(directory: str | os.PathLike, listen: list[str] | None = None):
    """The router's zenoh.Config (mTLS listener, access control) from a fleet directory or DIR/router."""
    return secure_config(directory, "router", listen=listen)


# --------------------------------------------------------------------------- swarm secure init


@dataclass(frozen=True)
class Written:
    """What init_fleet did: the fleet directory, the identity folders written, the robots revoked."""

    directory: Path
    folders: tuple[Path, ...]
    issued: tuple[str, ...]  # common names whose certificate is new
    revoked: tuple[int, ...]
    manifest: dict


def _ours(path: Path) -> bool:
    return path.is_dir() and ((path / CERT).is_file() or path.name == "ca")


def init_fleet(directory: str | os.PathLike, robots: int, fleet: str = "default",
               router_hosts: tuple[str, ...] = (), port: int = DEFAULT_PORT,
               extra_robot_keys: tuple[str, ...] = (), force: bool = False, update: bool = False,
               revoke: tuple[int, ...] = ()) -> Written:
    """Write a fleet directory (see the module's docstring): a CA, the router's certificate (names:
    127.0.0.1, localhost and `router_hosts`), one client certificate per role and per robot, a
    zenoh.json5 per identity, the router's with the access control of the role table. The router
    listens on tls/127.0.0.1:port, or on every interface (tls/0.0.0.0:port) when `router_hosts` are
    given; robots, the viewer and the operator connect to the first router host (127.0.0.1 without
    one), the launcher, world, leader and recorder to 127.0.0.1.

    A non-empty directory is refused unless `force` (everything is made anew: new CA) or `update` (of
    a directory made here: the CA and the certificates are kept, robots up to `robots` are added,
    `revoke` ids lose their folder and get a deny rule, a certificate is issued anew when it expires within a
    day (the router's also when its hosts changed), every zenoh.json5 is written again; the router must restart
    to apply it)."""
    import zenoh

    d = Path(directory)
    keys.check_fleet(fleet)
    if isinstance(robots, bool) or not isinstance(robots, int) or robots < 1:
        raise SecureError(f"--robots must be an integer >= 1, got {robots!r}")
    if not isinstance(port, int) or not 0 < port < 65536:
        raise SecureError(f"--port must be in 1..65535, got {port!r}")
    if force and update:
        raise SecureError("give --force (start anew) or --update (keep the CA), not both")
    if revoke and not update:
        raise SecureError("--revoke works on an existing fleet directory: add --update")
    for h in router_hosts:
        if not h or "/" in h or h.startswith("[") or ":" in h and not _is_ip(h):
            raise SecureError(f"--router-host {h!r}: give a host name or an IP address")
    for t in extra_robot_keys:
        try:
            zenoh.KeyExpr(roles.extra_expression(t, 0))
        except Exception as e:
            raise SecureError(f"--extra-robot-keys {t!r}: not a key expression ({e})") from None
        if "{id}" not in t:
            raise SecureError(f"--extra-robot-keys {t!r}: must contain {{id}} (each robot gets its own keys)")
        if t.startswith(keys.PREFIX + "/"):
            raise SecureError(f"--extra-robot-keys {t!r}: the {keys.PREFIX}/ keys are granted by the role table")
    revoked: set[int] = set()
    old = None
    if d.exists() and not d.is_dir():
        raise SecureError(f"{d}: exists and is not a directory")
    if update:
        old = read_manifest(d)
        if old["fleet"] != fleet:
            raise SecureError(f"{d} is fleet {old['fleet']!r}, not {fleet!r}: --update keeps the fleet "
                              "(start anew with --force)")
        if robots < old["robots"]:
            raise SecureError(f"{d} has robots 0..{old['robots'] - 1}: --update does not remove robots "
                              "(revoke them with --revoke)")
        revoked = set(old.get("revoked", []))
        for i in revoke:
            if not 0 <= i < max(robots, old["robots"]):
                raise SecureError(f"--revoke {i}: the fleet has robots 0..{max(robots, old['robots']) - 1}")
        revoked |= set(revoke)
    elif d.exists() and any(d.iterdir()):
        if not force:
            raise SecureError(f"{d} is not empty: give --force to replace its credentials (a new CA: every "
                              "process needs its new folder), or --update to add robots or revoke some")
        for p in d.iterdir():
            if _ours(p):
                shutil.rmtree(p)
        (d / MANIFEST).unlink(missing_ok=True)
    hosts = tuple(dict.fromkeys((*LOCAL_HOSTS, *router_hosts)))
    d.mkdir(parents=True, exist_ok=True)
    ca_dir = d / "ca"
    issued: list[str] = []
    if update and (ca_dir / CA).is_file():
        ca_cert, ca_key = _load_cert(ca_dir / CA), _load_key(ca_dir / "ca-key.pem")
    elif update:
        raise SecureError(f"{ca_dir / CA} is missing: --update needs the CA that signed the fleet")
    else:
        ca_dir.mkdir(mode=0o700)
        ca_key = _key()
        ca_name = _name(f"swarm CA {fleet}", fleet)
        ca_cert = _certificate(ca_key, ca_name, ca_key, ca_name, CA_DAYS, ca=True)
        _write(ca_dir / CA, _pem_cert(ca_cert))
        _write(ca_dir / "ca-key.pem", _pem_key(ca_key), secret=True)
    ca_pem = _pem_cert(ca_cert)
    # other machines reach the router by one of router_hosts: it listens on every interface then
    listen = [endpoint("0.0.0.0" if router_hosts else "127.0.0.1", port)]
    remote = [endpoint(router_hosts[0] if router_hosts else "127.0.0.1", port)]  # robots, viewers, operators
    local = [endpoint("127.0.0.1", port)]  # the launcher, world, leader and recorder run next to the router
    acl = access_control(fleet, robots, tuple(extra_robot_keys), tuple(sorted(revoked)))
    folders = []
    for role, i in roles.identities(robots):
        cn = roles.common_name(role, i)
        folder = d / cn
        if role == "robot" and i in revoked:
            if folder.exists():
                shutil.rmtree(folder)
            continue
        names = hosts if role == "router" else ()
        if not _keep(folder, names, update):
            folder.mkdir(mode=0o700, exist_ok=True)
            key = _key()
            cert = _certificate(key, _name(cn, fleet), ca_key, ca_cert.subject, CERT_DAYS, ca=False, hosts=names)
            _write(folder / KEY, _pem_key(key), secret=True)
            _write(folder / CERT, _pem_cert(cert))
            issued.append(cn)
        _write(folder / CA, ca_pem)
        doc = _router_doc(listen, acl) if role == "router" else \
            _client_doc(remote if role in ("robot", "viz", "operator") else local)
        _write(folder / CONFIG, (json.dumps(doc, indent=2) + "\n").encode())
        folders.append(folder)
    manifest = {"fleet": fleet, "robots": robots, "port": port, "router_hosts": list(router_hosts),
                "listen": listen, "extra_robot_keys": list(extra_robot_keys), "revoked": sorted(revoked),
                "ca_days": CA_DAYS, "cert_days": CERT_DAYS}
    _write(d / MANIFEST, (json.dumps(manifest, indent=2) + "\n").encode())
    return Written(d, tuple(folders), tuple(issued), tuple(sorted(set(revoke))), manifest)


def _is_ip(h: str) -> bool:
    try:
        ipaddress.ip_address(h)
        return True
    except ValueError:
        return False


def _keep(folder: Path, hosts: tuple[str, ...], update: bool) -> bool:
    """Whether an update keeps the certificate in `folder` (it exists, is valid for another day at least and, for
    the router, names exactly `hosts`): an expired one is issued anew."""
    if not update or not (folder / CERT).is_file() or not (folder / KEY).is_file():
        return False
    from cryptography import x509

    cert = _load_cert(folder / CERT)
    if cert.not_valid_after_utc < datetime.datetime.now(datetime.timezone.utc) + datetime.timedelta(days=1):
        return False
    if not hosts:
        return True
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return False
    have = {str(v) for v in san.get_values_for_type(x509.IPAddress)} | set(san.get_values_for_type(x509.DNSName))
    return have == {str(ipaddress.ip_address(h)) if _is_ip(h) else h for h in hosts}

"""`swarm secure init`: what the fleet directory holds, how an identity is found (a robot's id is its
certificate's), adding and revoking robots, and the command line."""

from __future__ import annotations

import json
import shutil
import stat

import pytest
import zenoh
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from swarm.cli.main import main
from swarm.net import secure
from swarm.proto import keys, roles
from tests.security.conftest import FLEET, ROBOTS, Net, Seen

pytestmark = pytest.mark.timeout(60)


def _cert(path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


@pytest.mark.unit
def test_the_directory_holds_a_folder_per_identity(fleet_dir):
    assert (fleet_dir / "ca" / "ca.pem").is_file() and (fleet_dir / "ca" / "ca-key.pem").is_file()
    for role, i in roles.identities(ROBOTS):
        folder = fleet_dir / roles.common_name(role, i)
        assert sorted(p.name for p in folder.iterdir()) == ["ca.pem", "cert.pem", "key.pem", "zenoh.json5"]
        assert stat.S_IMODE((folder / "key.pem").stat().st_mode) == 0o600
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert stat.S_IMODE((fleet_dir / "ca" / "ca-key.pem").stat().st_mode) == 0o600
    m = json.loads((fleet_dir / "fleet.json").read_text())
    assert (m["fleet"], m["robots"], m["port"], m["revoked"]) == (FLEET, ROBOTS, 7447, [])


@pytest.mark.unit
@pytest.mark.parametrize("role, i", [("robot", 4), ("world", 0), ("viz", 0), ("router", 0)])
def test_certificates_name_their_identity_and_are_signed_by_the_ca(fleet_dir, role, i):
    ca = _cert(fleet_dir / "ca" / "ca.pem")
    cert = _cert(fleet_dir / roles.common_name(role, i) / "cert.pem")
    cert.verify_directly_issued_by(ca)
    assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == roles.common_name(role, i)
    assert cert.subject.get_attributes_for_oid(NameOID.ORGANIZATIONAL_UNIT_NAME)[0].value == FLEET
    days = (cert.not_valid_after_utc - cert.not_valid_before_utc).days
    assert secure.CERT_DAYS <= days <= secure.CERT_DAYS + 1
    usage = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    assert ExtendedKeyUsageOID.CLIENT_AUTH in usage
    assert (ExtendedKeyUsageOID.SERVER_AUTH in usage) == (role == "router")
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca


@pytest.mark.unit
def test_the_router_certificate_names_its_hosts(tmp_path):
    w = secure.init_fleet(tmp_path / "f", 1, "f", router_hosts=("10.0.0.7", "hub.lan"), port=7500)
    san = _cert(tmp_path / "f" / "router" / "cert.pem").extensions.get_extension_for_class(
        x509.SubjectAlternativeName).value
    assert {str(a) for a in san.get_values_for_type(x509.IPAddress)} == {"127.0.0.1", "10.0.0.7"}
    assert set(san.get_values_for_type(x509.DNSName)) == {"localhost", "hub.lan"}
    doc = lambda who: json.loads((tmp_path / "f" / who / "zenoh.json5").read_text())  # noqa: E731
    assert doc("router")["listen"]["endpoints"] == ["tls/0.0.0.0:7500"]
    assert doc("robot-0")["connect"]["endpoints"] == ["tls/10.0.0.7:7500"]
    assert doc("world")["connect"]["endpoints"] == ["tls/127.0.0.1:7500"]
    assert w.manifest["listen"] == ["tls/0.0.0.0:7500"]


@pytest.mark.unit
def test_configs_are_mutual_tls_with_files_of_their_own_folder(fleet_dir):
    doc = json.loads((fleet_dir / "robot-2" / "zenoh.json5").read_text())
    tls = doc["transport"]["link"]["tls"]
    assert (doc["mode"], doc["connect"]["endpoints"], doc["transport"]["link"]["protocols"]) == \
        ("client", ["tls/127.0.0.1:7447"], ["tls"])
    assert tls == {"root_ca_certificate": "ca.pem", "connect_certificate": "cert.pem", "connect_private_key": "key.pem",
                   "enable_mtls": True, "verify_name_on_connect": True, "close_link_on_expiration": True}
    router = json.loads((fleet_dir / "router" / "zenoh.json5").read_text())
    assert router["access_control"]["default_permission"] == "deny" and router["access_control"]["enabled"]
    assert {s["id"] for s in router["access_control"]["subjects"]} == {roles.common_name(*x)
                                                                       for x in roles.identities(ROBOTS)}
    conf = secure.secure_config(fleet_dir, "robot", 2, connect=["tls/127.0.0.1:9999"])
    assert json.loads(conf.get_json("transport/link/tls/connect_certificate")) == str(fleet_dir / "robot-2" / "cert.pem")
    assert json.loads(conf.get_json("connect/endpoints")) == ["tls/127.0.0.1:9999"]
    with pytest.raises(secure.SecureError, match="tls/HOST:PORT"):
        secure.secure_config(fleet_dir, "robot", 2, connect=["tcp/127.0.0.1:9999"])


@pytest.mark.unit
@pytest.mark.parametrize("where, role, i, found", [
    ("", "robot", 3, ("robot", 3)),  # the fleet directory: its folder for the identity
    ("robot-3", "robot", 3, ("robot", 3)),
    ("robot-3", "robot", None, ("robot", 3)),  # a robot's own folder: its id from the certificate
    ("world", "world", None, ("world", 0)),
])
def test_find_identity(fleet_dir, where, role, i, found):
    ident = secure.find_identity(fleet_dir / where if where else fleet_dir, role, i)
    assert (ident.role, ident.id, ident.fleet) == (*found, FLEET)
    assert ident.folder == fleet_dir / roles.common_name(*found)


@pytest.mark.unit
@pytest.mark.parametrize("where, role, i, message", [
    ("robot-3", "robot", 5, "its id is 3, not 5"),  # swarm robot --secure DIR/robot-3 --id 5
    ("robot-3", "world", None, "robot-3, not of a world"),
    ("", "robot", None, "needs its id"),
    ("", "robot", 99, "no credentials for robot-99"),
    ("ca", "robot", 3, "neither a fleet directory"),
    ("nowhere", "world", None, "no such directory"),
])
def test_find_identity_refuses(fleet_dir, where, role, i, message):
    with pytest.raises(secure.SecureError, match=message):
        secure.find_identity(fleet_dir / where if where else fleet_dir, role, i)


@pytest.mark.unit
def test_robot_id_of(fleet_dir):
    assert secure.robot_id_of(fleet_dir / "robot-4") == 4
    assert secure.robot_id_of(fleet_dir / "leader") is None


@pytest.mark.integration
def test_a_robot_folder_alone_is_enough(fleet_dir, tmp_path):
    """Copied elsewhere (another machine), robot 2's folder still connects as robot 2."""
    alone = tmp_path / "on-the-robot"
    shutil.copytree(fleet_dir / "robot-2", alone)
    with Net(fleet_dir, secure_=True) as net:
        seen = Seen()
        net.bus("world").subscribe(keys.robot_any(FLEET, "status"), seen.add)
        robot = net.bus("robot", 2, directory=alone)
        seen.retry(lambda: robot.put(keys.robot_status(FLEET, 2), b"from its own folder"), bool, "robot 2's status")


@pytest.mark.integration
def test_update_adds_robots_and_revokes_with_the_same_ca(tmp_path):
    d = tmp_path / "f"
    secure.init_fleet(d, 3, FLEET)
    ca = (d / "ca" / "ca.pem").read_bytes()
    kept = (d / "robot-0" / "cert.pem").read_bytes()
    revoked = tmp_path / "revoked-robot-1"
    shutil.copytree(d / "robot-1", revoked)  # what robot 1's machine still holds
    w = secure.init_fleet(d, 5, FLEET, update=True, revoke=(1,))
    assert (d / "ca" / "ca.pem").read_bytes() == ca and (d / "robot-0" / "cert.pem").read_bytes() == kept
    assert set(w.issued) == {"robot-3", "robot-4"} and w.revoked == (1,)
    assert not (d / "robot-1").exists() and json.loads((d / "fleet.json").read_text())["revoked"] == [1]
    # a later update keeps robot 1 revoked (never issued again)
    secure.init_fleet(d, 6, FLEET, update=True)
    assert not (d / "robot-1").exists()
    with pytest.raises(secure.SecureError, match=r"revoked"):
        secure.find_identity(d, "robot", 1)
    with Net(d, secure_=True) as net:
        seen = Seen()
        world = net.bus("world")
        world.subscribe(keys.robot_any(FLEET, "status"), seen.add)
        world.subscribe(f"{keys.base(FLEET)}/cell/*/*/*", seen.add)
        r4 = net.bus("robot", 4)  # a new robot, same CA
        seen.retry(lambda: r4.put(keys.robot_status(FLEET, 4), b"new"), bool, "robot 4's status")
        r1 = net.bus("robot", 1, directory=revoked)  # its certificate is still valid: it connects...
        r1.put(keys.robot_status(FLEET, 1), b"revoked")  # ...but every message is denied
        r1.put(keys.cell(FLEET, 0, 0, 1), b"revoked")
        r4.put(keys.robot_status(FLEET, 4), b"sentinel")
        items = seen.wait_key(keys.robot_status(FLEET, 4), b"sentinel")
        assert [k for k, _ in items if k != keys.robot_status(FLEET, 4)] == []


@pytest.mark.unit
def test_update_issues_anew_a_certificate_that_expires_within_a_day(tmp_path, monkeypatch):
    """The fix the client's error names for an expired router certificate (swarm secure init DIR --update):
    certificates valid for less than a day are issued anew with the same CA, the others are kept."""
    from cryptography import x509

    d = tmp_path / "f"
    monkeypatch.setattr(secure, "CERT_DAYS", 0)  # every certificate ends now
    secure.init_fleet(d, 2, FLEET)
    monkeypatch.undo()
    ca = (d / "ca" / "ca.pem").read_bytes()
    w = secure.init_fleet(d, 2, FLEET, update=True)
    assert {"router", "robot-0", "robot-1"} <= set(w.issued) and (d / "ca" / "ca.pem").read_bytes() == ca
    cert = x509.load_pem_x509_certificate((d / "router" / "cert.pem").read_bytes())
    assert (cert.not_valid_after_utc - cert.not_valid_before_utc).days > 800
    assert secure.init_fleet(d, 2, FLEET, update=True).issued == ()  # valid now: kept


@pytest.mark.integration
def test_force_makes_a_new_ca_and_old_certificates_are_refused(tmp_path):
    d = tmp_path / "f"
    secure.init_fleet(d, 2, FLEET)
    old = tmp_path / "old-robot-0"
    shutil.copytree(d / "robot-0", old)
    (d / "notes.txt").write_text("the user's own file")
    with pytest.raises(secure.SecureError, match="not empty"):
        secure.init_fleet(d, 2, FLEET)
    secure.init_fleet(d, 2, FLEET, force=True)
    assert (d / "notes.txt").read_text() == "the user's own file"
    with Net(d, secure_=True) as net:
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(net.config("robot", 0, directory=old)).close()
        net.bus("robot", 0)  # the new one connects


@pytest.mark.unit
@pytest.mark.parametrize("kwargs, message", [
    ({"robots": 0}, "--robots"),
    ({"fleet": "bad fleet"}, "fleet name"),
    ({"port": 70000}, "--port"),
    ({"router_hosts": ("tls/host",)}, "--router-host"),
    ({"extra_robot_keys": ("rt/cmd_vel",)}, "must contain"),
    ({"extra_robot_keys": ("swarm/{id}/x",)}, "granted by the role table"),
    ({"extra_robot_keys": ("a//{id}",)}, "not a key expression"),
    ({"revoke": (1,)}, "--update"),
    ({"force": True, "update": True}, "not both"),
])
def test_init_refuses(tmp_path, kwargs, message):
    args = {"robots": 2, "fleet": FLEET, **kwargs}
    with pytest.raises((secure.SecureError, keys.KeyError_), match=message):
        secure.init_fleet(tmp_path / "f", **args)


@pytest.mark.unit
def test_update_refuses_another_fleet_and_fewer_robots(tmp_path):
    secure.init_fleet(tmp_path / "f", 3, FLEET)
    with pytest.raises(secure.SecureError, match="keeps the fleet"):
        secure.init_fleet(tmp_path / "f", 3, "other", update=True)
    with pytest.raises(secure.SecureError, match="does not remove robots"):
        secure.init_fleet(tmp_path / "f", 2, FLEET, update=True)


@pytest.mark.unit
def test_extra_robot_keys_reach_the_acl(tmp_path):
    secure.init_fleet(tmp_path / "f", 2, FLEET, extra_robot_keys=("robot{id}/cmd_vel",))
    acl = json.loads((tmp_path / "f" / "router" / "zenoh.json5").read_text())["access_control"]
    robot1 = [r for r in acl["rules"] if r["id"].startswith("robot-1/")]
    assert any("robot1/cmd_vel" in r["key_exprs"] and "put" in r["messages"] for r in robot1)
    assert not any("robot0/cmd_vel" in r["key_exprs"] for r in robot1)


@pytest.mark.unit
def test_the_command_line(tmp_path, capsys):
    d = tmp_path / "fleet"
    assert main(["secure", "init", str(d), "--robots", "2", "--fleet", "cli", "--port", "7600"]) == 0
    out = capsys.readouterr().out
    assert "robot-<i>/" in out and f"--secure {d}" in out and "tls/127.0.0.1:7600" in out
    assert secure.find_identity(d, "robot", 1).fleet == "cli"
    assert main(["secure", "init", str(d), "--robots", "2"]) == 2
    assert "not empty" in capsys.readouterr().err
    # --update keeps the fleet and the port from the manifest
    assert main(["secure", "init", str(d), "--robots", "3", "--update", "--revoke", "0"]) == 0
    m = json.loads((d / "fleet.json").read_text())
    assert (m["fleet"], m["port"], m["robots"], m["revoked"]) == ("cli", 7600, 3, [0])
    assert "restart the router" in capsys.readouterr().out
    assert main(["secure", "init", str(tmp_path / "none"), "--robots", "2", "--update"]) == 2
    assert main(["secure", "init", str(tmp_path / "g"), "--robots", "2", "--fleet", "a b"]) == 2


@pytest.mark.unit
def test_a_robot_given_only_its_folder_takes_its_id_from_the_certificate(fleet_dir, tmp_path, capsys):
    """docs/security.md: on a robot's machine, `swarm robot --secure robot-3/ --connect tls/...` with no --id:
    the id is the certificate's (it was refused: --id required). Without --secure, --id is still required;
    a folder that holds no robot's certificate is refused by name."""
    from swarm.cli.parser import build_parser
    from swarm.cli.robot import _id_of_secure_folder
    from swarm.cli.common import BadInput

    one = tmp_path / "robot-1"
    shutil.copytree(fleet_dir / roles.common_name("robot", 1), one)
    p = build_parser()
    args = p.parse_args(["robot", "--secure", str(one), "--connect", "tls/127.0.0.1:7447"])
    assert not hasattr(args, "id") and _id_of_secure_folder(args) == 1
    assert p.parse_args(["robot", "--id", "auto"]).id is None  # auto stays auto
    with pytest.raises(BadInput, match="--id is required"):
        _id_of_secure_folder(p.parse_args(["robot", "--connect", "tcp/127.0.0.1:7447"]))
    with pytest.raises(BadInput, match="no robot certificate"):
        _id_of_secure_folder(p.parse_args(["robot", "--secure", str(fleet_dir)]))  # a fleet directory: which robot?
    with pytest.raises(BadInput, match="not a robot's folder"):
        _id_of_secure_folder(p.parse_args(["robot", "--secure", str(fleet_dir / "router")]))

"""`swarm secure init DIR --robots N`: the credentials of `--secure` (swarm.net.secure; docs/security.md)."""

from __future__ import annotations

from pathlib import Path

from swarm.cli.common import EXIT_OK, BadInput


def cmd_secure_init(args, started: float) -> int:
    """Write (or, with --update, extend) a fleet directory and say what goes where."""
    from swarm.net import secure

    d = Path(args.directory)
    old = None
    if args.update:
        try:
            old = secure.read_manifest(d)
        except secure.SecureError as e:
            raise BadInput(f"--update: {e}") from None
    fleet = args.fleet or (old["fleet"] if old else "default")
    port = args.port or (old["port"] if old else secure.DEFAULT_PORT)
    hosts = tuple(args.router_host or (old["router_hosts"] if old else ()))
    extra = tuple(args.extra_robot_keys or (old["extra_robot_keys"] if old else ()))
    try:
        w = secure.init_fleet(d, args.robots, fleet, router_hosts=hosts, port=port, extra_robot_keys=extra,
                              force=args.force, update=args.update, revoke=tuple(args.revoke))
    except (secure.SecureError, ValueError) as e:
        raise BadInput(str(e)) from None
    except OSError as e:
        where = f"{e.filename}: " if e.filename else ""
        raise BadInput(f"{d}: cannot make or read the fleet directory there ({where}{e.strerror or e})") from None
    m = w.manifest
    robots = [p.name for p in w.folders if p.name.startswith("robot-")]
    print(f"swarm secure: {'updated' if args.update else 'wrote'} {d} for fleet '{m['fleet']}': "
          f"{len(w.folders)} identities ({len(robots)} robots), {len(w.issued)} new certificates")
    if w.revoked:
        print(f"  revoked robots {', '.join(map(str, w.revoked))}: their folders are gone and the router denies them")
    print(f"  {d / 'ca'}/            the certificate authority; ca-key.pem signs new robots (--update): keep it "
          "off the robots' machines")
    print(f"  {d / 'router'}/        the router: listens on {', '.join(m['listen'])}, holds the access control")
    print(f"  {d}/<role>/          launcher, world, leader, viz, recorder, operator: one folder each")
    print(f"  {d}/robot-<i>/       robot i's own folder: copy it, and only it, to robot i's machine")
    if args.update:
        print("next: restart the router (its access control is read once, at start); running robots keep "
              "their certificates")
    else:
        print(f"next: swarm up --robots {m['robots']} --fleet {m['fleet']} --secure {d}   (on another machine: "
              f"swarm robot --secure {d}/robot-I --connect tls/HOST:{m['port']})")
    return EXIT_OK

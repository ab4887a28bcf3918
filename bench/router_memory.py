"""What oversized payloads cost `swarm router` in memory: its RSS before and after an attacker's puts.

    python bench/router_memory.py [--puts 12] [--mib 64] [--settle 2]

Starts `swarm router` as the product does (python -m swarm.cli router, its own process group, a free
loopback port), then two client sessions: a subscriber with swarm's configuration (swarm.net.bus.zenoh_config)
on a robot's command key, and an attacker: a plain zenoh.Config() client (no size filter, zenoh's 1 GiB
max_message_size, multicast scouting off) that declares a liveliness token, puts `--puts` payloads of
`--mib` MiB on swarm/<fleet>/robot/3/cmd (congestion control BLOCK: every fragment is sent), then a small
put on the same key. When that small put reaches the subscriber the router has handled everything before it
(one link, in order). Prints the router's VmRSS (/proc/<pid>/status) before, right after and `--settle`
seconds later, its peak (VmHWM), how many oversized payloads reached the subscriber (0 expected) and
whether the attacker's session stayed up (its token never went down). docs/security.md quotes it.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

FLEET = "mem"
WAIT_S = 20.0  # the longest any one wait may take


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss_mib(pid: int, field: str = "VmRSS") -> float:
    """A process's resident memory (VmRSS) or its peak so far (VmHWM), in MiB, from /proc/<pid>/status."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no {field} for pid {pid}")


def start_router(endpoint: str, fleet: str, log_path: Path) -> subprocess.Popen:
    with open(log_path, "wb") as log:
        return subprocess.Popen([sys.executable, "-m", "swarm.cli", "router", "--listen", endpoint, "--fleet", fleet,
                                 "--log-level", "warning"], stdin=subprocess.DEVNULL, stdout=log,
                                stderr=subprocess.STDOUT, process_group=0, cwd=ROOT)


def open_until(conf_fn, deadline: float):
    """A zenoh session of conf_fn(), retried until the router accepts it (it starts asynchronously)."""
    import zenoh

    while True:
        try:
            return zenoh.open(conf_fn())
        except Exception:
            if time.monotonic() >= deadline:
                raise
            time.sleep(0.1)


class Seen:
    """Payload sizes on the watched key, and the attacker's token going down; wait_for blocks on a condition."""

    def __init__(self) -> None:
        self.sizes: list[int] = []
        self.payloads: list[bytes] = []
        self.token_up = self.token_down = False
        self.cond = threading.Condition()

    def sample(self, s) -> None:
        p = s.payload.to_bytes()
        with self.cond:
            self.sizes.append(len(p))
            self.payloads.append(p if len(p) < 64 else b"")
            self.cond.notify_all()

    def alive(self, s) -> None:
        import zenoh

        with self.cond:
            if s.kind == zenoh.SampleKind.DELETE:
                self.token_down = True
            else:
                self.token_up = True
            self.cond.notify_all()

    def wait_for(self, pred, what: str, timeout_s: float = WAIT_S) -> None:
        with self.cond:
            if not self.cond.wait_for(pred, timeout=timeout_s):
                raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def run(puts: int, mib: float, settle_s: float) -> dict:
    import zenoh

    from swarm.launch.child import stop_group
    from swarm.net.bus import plain_config, zenoh_config
    from swarm.proto import keys

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    fd, name = tempfile.mkstemp(prefix="router_memory_", suffix=".log")
    os.close(fd)
    log = Path(name)
    router = start_router(endpoint, FLEET, log)
    sessions = []
    ok = False
    try:
        deadline = time.monotonic() + WAIT_S
        sub_s = open_until(lambda: zenoh_config("client", connect=[endpoint]), deadline)
        sessions.append(sub_s)
        while not list(sub_s.liveliness().get(keys.alive(FLEET, "router"), timeout=1.0)):  # the router's token
            assert time.monotonic() < deadline, "the router's liveliness token did not appear"
        atk = open_until(lambda: plain_config("client", connect=[endpoint]), deadline)
        sessions.append(atk)
        seen = Seen()
        key = keys.robot_cmd(FLEET, 3)
        sub_s.declare_subscriber(key, seen.sample)
        sub_s.liveliness().declare_subscriber("attacker/alive", seen.alive, history=True)
        token = atk.liveliness().declare_token("attacker/alive")  # kept: a dropped token is undeclared
        pub = atk.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)

        def ping(tag: bytes) -> None:  # a small put until it reaches the subscriber (its route settles first)
            end = time.monotonic() + WAIT_S
            while True:
                pub.put(tag)
                try:
                    seen.wait_for(lambda: tag in seen.payloads, f"{tag!r} through the router", 0.2)
                    return
                except AssertionError:
                    assert time.monotonic() < end, f"{tag!r} never reached the subscriber"

        seen.wait_for(lambda: seen.token_up, "the attacker's token")
        ping(b"warm-up")
        before = rss_mib(router.pid)
        big = bytes(int(mib * (1 << 20)))
        t0 = time.monotonic()
        for _ in range(puts):
            pub.put(big)
        ping(b"after")
        took = time.monotonic() - t0
        right_after, peak = rss_mib(router.pid), rss_mib(router.pid, "VmHWM")
        time.sleep(settle_s)  # what the router keeps, not what it holds while it frees
        settled = rss_mib(router.pid)
        out = {"puts": puts, "mib": mib, "before": before, "after": right_after, "settled": settled, "peak": peak,
               "took_s": took, "oversized_delivered": sum(1 for n in seen.sizes if n > 1 << 20),
               "attacker_token_down": seen.token_down, "router_alive": router.poll() is None}
        token.undeclare()
        ok = True
        return out
    finally:
        for s in reversed(sessions):
            s.close()
        stop_group(router)
        if ok:
            log.unlink(missing_ok=True)
        else:
            print(f"the router's log: {log}", file=sys.stderr)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--puts", type=int, default=12)
    ap.add_argument("--mib", type=float, default=64)
    ap.add_argument("--settle", type=float, default=2.0, help="seconds after the last put before the last reading")
    a = ap.parse_args()
    r = run(a.puts, a.mib, a.settle)
    print(f"{r['puts']} puts of {r['mib']:g} MiB in {r['took_s']:.1f} s: router RSS {r['before']:.0f} MiB before, "
          f"{r['after']:.0f} MiB right after, {r['settled']:.0f} MiB {a.settle:g} s later "
          f"(+{r['settled'] - r['before']:.0f} MiB), peak {r['peak']:.0f} MiB; "
          f"oversized payloads delivered: {r['oversized_delivered']}; "
          f"attacker's session closed: {r['attacker_token_down']}; router alive: {r['router_alive']}")


if __name__ == "__main__":
    main()

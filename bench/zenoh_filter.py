"""What a received message costs a swarm session, with zenoh's size filter and the key hints or without.

    python bench/zenoh_filter.py [--seconds 8] [--rounds 2]

Three processes on this machine: a router with swarm's configuration, a publisher that puts 8 states of
~90 bytes on 8 keys of one cell every millisecond, and a subscriber with a robot's 9 cell inboxes that
drains them every 10 ms. The subscriber's session comes in variants:
  full      swarm's session (swarm.net.bus.zenoh_config: the low_pass_filter size rules on ingress), the
            8 keys hinted (ZenohBus.hint), as a robot does
  no-hint   the same without the hints: zenoh matches every sample against the session's subscriptions
  no-ros    without the four ROS 2 rules that begin with ** (the cmd_vel and odom topics a drive uses)
  no-filter without any size rule
Prints the subscriber process's CPU (from /proc, user + system) per message received, the first 2.5 s
left out, for each variant in turn, `--rounds` times (the VM's speed drifts: compare within a round).
docs/performance.md quotes it.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

N_KEYS = 8
VARIANTS = ("full", "no-hint", "no-ros", "no-filter", "none")


def cpu_s() -> float:
    f = Path(f"/proc/{os.getpid()}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def session(mode: str, endpoint: str, variant: str = "full"):
    from swarm.net import bus as busmod

    rules = busmod.size_limits()
    if variant == "no-ros":
        for rule in rules:
            rule["key_exprs"] = [k for k in rule["key_exprs"] if not k.startswith("**")]
    elif variant in ("no-filter", "none"):
        rules = []
    busmod.size_limits = lambda: rules  # read by zenoh_config below
    conf = busmod.zenoh_config(mode, listen=[endpoint]) if mode == "router" else \
        busmod.zenoh_config(mode, connect=[endpoint], ingress_checks=variant != "none")
    return busmod.ZenohBus(conf)


def role(name: str, endpoint: str, seconds: float, variant: str) -> None:
    if name == "router":
        with session("router", endpoint):
            print("READY", flush=True)
            time.sleep(seconds + 4)
    elif name == "pub":
        with session("client", endpoint) as bus:
            time.sleep(1.5)  # the subscriber's inboxes reach the router
            keys = [f"swarm/f/cell/1/1/{j}" for j in range(N_KEYS)]
            payload, end = bytes(90), time.monotonic() + seconds
            while time.monotonic() < end:
                for k in keys:
                    bus.put(k, payload)
                time.sleep(0.001)
    else:
        with session("client", endpoint, variant) as bus:
            boxes = [bus.inbox(f"swarm/f/cell/{a}/{b}/*", depth=256) for a in (0, 1, 2) for b in (0, 1, 2)]
            if variant != "no-hint":
                for j in range(N_KEYS):
                    bus.hint(f"swarm/f/cell/1/1/{j}")
            n, t0, c0, n0 = 0, time.monotonic(), None, 0
            while time.monotonic() - t0 < seconds:
                time.sleep(0.01)
                got = sum(len(b.drain()) for b in boxes)
                if c0 is None and time.monotonic() - t0 > 2.5:
                    c0, n0 = cpu_s(), n
                n += got
            msgs = n - n0
            print(json.dumps({"variant": variant, "messages": msgs,
                              "cpu_us_per_message": 1e6 * (cpu_s() - c0) / max(1, msgs)}), flush=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=8.0, help="seconds the publisher runs a variant (default 8)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--role", choices=("router", "pub", "sub"), help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", help=argparse.SUPPRESS)
    ap.add_argument("--variant", default="full", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.role is not None:
        role(a.role, a.endpoint, a.seconds, a.variant)
        return 0
    if a.seconds < 4 or a.rounds < 1:
        ap.error("--seconds must be at least 4 and --rounds at least 1")
    me = [sys.executable, __file__, "--seconds", str(a.seconds)]
    for r in range(a.rounds):
        for variant in VARIANTS:
            ep = f"tcp/127.0.0.1:{free_port()}"
            router = subprocess.Popen(me + ["--role", "router", "--endpoint", ep], stdout=subprocess.PIPE, text=True,
                                      start_new_session=True)
            try:
                if router.stdout.readline().strip() != "READY":
                    raise SystemExit("zenoh_filter: the router did not start")
                pub = subprocess.Popen(me + ["--role", "pub", "--endpoint", ep], start_new_session=True)
                sub = subprocess.run(me + ["--role", "sub", "--endpoint", ep, "--variant", variant],
                                     capture_output=True, text=True, timeout=a.seconds + 60)
                pub.wait(timeout=30)
                if sub.returncode != 0 or not sub.stdout.strip():
                    raise SystemExit(f"zenoh_filter: the {variant} subscriber exited {sub.returncode}:\n{sub.stderr[-2000:]}")
                got = json.loads(sub.stdout.strip().splitlines()[-1])
                print(f"round {r + 1}  {variant:>9}: {got['cpu_us_per_message']:5.2f} us a message "
                      f"({got['messages']} messages)", flush=True)
            finally:
                router.terminate()
                router.wait(timeout=30)
    return 0


if __name__ == "__main__":
    sys.exit(main())

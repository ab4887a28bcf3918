"""Shared helpers of the multi-process tests: free ports, `swarm up` command lines, bounded waits on
the world's progress, killing what a test started by PID."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(pred, timeout_s: float, what: str, poke=None, every_s: float = 0.02):
    """pred()'s first truthy value within timeout_s, else AssertionError naming `what` (for conditions
    with no event to wait on: a file, a log line, a process, what a listener heard). poke() runs between
    tries: a new zenoh subscription reaches the router asynchronously, so a first message may need
    repeating."""
    end = time.monotonic() + timeout_s
    while True:
        got = pred()
        if got:
            return got
        if time.monotonic() >= end:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        if poke is not None:
            poke()
        time.sleep(every_s)


def up(tmp_path: Path, *args: str, fleet: str = "t") -> tuple[list[str], Path]:
    metrics = tmp_path / "metrics.json"
    timeout = () if "--start-timeout" in args else ("--start-timeout", "60")  # a flag given twice is refused
    cmd = [sys.executable, "-m", "swarm.cli", "up", "--listen", f"tcp/127.0.0.1:{free_port()}", "--fleet", fleet,
           "--metrics", str(metrics), "--log-dir", str(tmp_path / "logs"), *timeout, "--no-viz", *args]
    return cmd, metrics


def wait_for_ticks(cmd: list[str] | str, fleet: str, tick: int, proc: subprocess.Popen,
                   timeout_s: float = 90.0) -> None:
    """Wait (bounded) until the world of `swarm up` (command line `cmd`, or a router's endpoint) reports
    tick `tick` on its progress key: an event to wait on instead of a sleep. `proc` must stay alive."""
    from swarm.proto import keys, protocol
    from swarm.net.bus import ZenohBus, zenoh_config

    endpoint = cmd[cmd.index("--listen") + 1] if isinstance(cmd, list) else cmd
    seen = threading.Event()

    def on_progress(key: str, payload: bytes) -> None:
        if protocol.decode(payload, "progress").seq >= tick:
            seen.set()

    deadline = time.monotonic() + timeout_s
    bus = None
    try:
        while bus is None:  # the router may not listen yet
            try:
                bus = ZenohBus(zenoh_config(connect=[endpoint]))
            except Exception:
                assert time.monotonic() < deadline and proc.poll() is None, "the router never came up"
                time.sleep(0.1)
        bus.subscribe(keys.world_progress(fleet), on_progress)
        while not seen.wait(0.2):
            assert proc.poll() is None, proc.communicate()[1]
            assert time.monotonic() < deadline, f"no progress message with tick >= {tick} in {timeout_s:g} s"
    finally:
        if bus is not None:
            bus.close()


@contextlib.contextmanager
def cpu_hogs(n: int):
    """n busy Python processes (a core's worth of demand each, at the caller's priority) for the `with` block;
    killed by their process groups on the way out, whatever happened."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True) for _ in range(n)]
    try:
        yield hogs
    finally:
        for h in hogs:
            os.killpg(h.pid, signal.SIGKILL)
            h.wait(10)


def child_of(proc: subprocess.Popen, role: str, robot_id: int | None = None) -> psutil.Process:
    """The `swarm <role>` child of a `swarm up` process (robot `robot_id` for role "robot")."""
    for p in descendants(proc.pid):
        try:
            line = p.cmdline()
        except psutil.NoSuchProcess:
            continue
        if len(line) > 3 and line[3] == role and (robot_id is None or line[line.index("--id") + 1] == str(robot_id)):
            return p
    raise AssertionError(f"no {role} child of swarm up")


def descendants(pid: int) -> list[psutil.Process]:
    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def kill_all(procs) -> None:
    for p in procs:
        try:
            p.kill()
        except psutil.NoSuchProcess:
            pass


class Procs:
    """Processes a test starts (`swarm ...` commands, each in its own process group, output to a log
    file); stop() kills every one of them and their children by PID."""

    def __init__(self, tmp_path: Path) -> None:
        self.tmp_path = tmp_path
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, *args: str) -> subprocess.Popen:
        log = open(self.tmp_path / f"{name}.log", "wb")
        p = subprocess.Popen([sys.executable, "-m", "swarm.cli", *args], stdin=subprocess.DEVNULL, stdout=log,
                             stderr=subprocess.STDOUT, process_group=0)
        log.close()
        self.procs[name] = p
        return p

    def log(self, name: str) -> str:
        return (self.tmp_path / f"{name}.log").read_text(errors="replace")

    def wait(self, name: str, timeout_s: float) -> int:
        return self.procs[name].wait(timeout_s)

    def stop(self) -> None:
        for p in self.procs.values():
            kill_all(descendants(p.pid))
            if p.poll() is None:
                p.kill()
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                pass

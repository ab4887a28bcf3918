"""`swarm up`'s supervisor: the one place that starts processes (subprocess).

    with Supervisor(plan, log_dir) as sup:
        sup.start(spec)                # each child in its own process group, its log in log_dir
        sup.check_restarts()           # restart robots and the leader that exited (RestartPolicy)
                                       # leaving: SIGTERM to every group, SIGKILL after a grace

Children never fork after a zenoh session is open (subprocess starts a fresh interpreter). They
die with the launcher even if it is SIGKILLed (PR_SET_PDEATHSIG: swarm.process).
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections import deque
from pathlib import Path

from swarm.process import PARENT_ENV
from swarm.launch.plan import Plan, ProcSpec

# --------------------------------------------------------------------------- children


PACKAGES = ("swarm", "agents", "world")  # this project's code, which every child process imports


def compile_project() -> None:
    """Compile this project's modules to bytecode once, here, before forty processes import them.

    Each child would otherwise compile every module of ours it imports (~40 ms of CPU each, twice
    that on a busy machine) wherever Python does not write bytecode by itself: the first run after
    an install from source, PYTHONDONTWRITEBYTECODE. That was about 1 s of a 2-core machine's
    launch. The .pyc files go where Python looks for them (__pycache__ next to the sources); a
    module is compiled only when its source changed; where the sources are read-only nothing is
    written (an installed wheel has its bytecode already)."""
    import compileall
    import importlib.util

    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        for where in (spec.submodule_search_locations or []) if spec is not None else []:
            if os.access(where, os.W_OK):
                try:
                    compileall.compile_dir(where, quiet=2)
                except OSError:  # a file we may not write: that module is compiled by each child, as before
                    pass


class Child:
    def __init__(self, spec: ProcSpec, proc: subprocess.Popen, log: Path):
        self.spec, self.proc, self.log = spec, proc, log
        self.restarts: deque[float] = deque()
        self.given_up = False
        self.scheduled = False  # killed by a scheduled fault: the restart policy leaves it (the rule restarts it)

    @property
    def pid(self) -> int:
        return self.proc.pid


class Supervisor:
    """Starts children in their own process groups and makes sure none outlives it."""

    def __init__(self, plan: Plan, log_dir: Path, grace_s: float = 3.0):
        self.plan, self.log_dir, self.grace_s = plan, log_dir, grace_s
        self.children: dict[str, Child] = {}
        self.env = {**os.environ, **dict(plan.env), PARENT_ENV: str(os.getpid())}
        # why the run cannot go on: a robot refused it (REFUSED_EXIT: the run's own law raised or gave a non-finite
        # command, or this machine's copy differs); the launcher ends the run with this text
        self.fatal: str | None = None
        self.restarted = 0  # robot processes restarted
        self.leader_restarted = 0

    def __enter__(self) -> "Supervisor":
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()

    def log_of(self, spec: ProcSpec) -> Path:
        """The child's log file (appended to: a reused --log-dir keeps earlier runs' lines)."""
        return self.log_dir / (spec.name.replace(" ", "-") + ".log")

    def start(self, spec: ProcSpec, env: dict[str, str] | None = None, pass_fds: tuple[int, ...] = ()) -> Child:
        """Start spec's process; env: variables for it alone, pass_fds: descriptors it inherits (a pipe)."""
        log = self.log_of(spec)
        with open(log, "ab") as out:
            proc = subprocess.Popen(spec.argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                    env={**self.env, **(env or {})}, process_group=0, pass_fds=pass_fds)
        old = self.children.get(spec.name)
        child = Child(spec, proc, log)
        if old is not None:
            child.restarts = old.restarts
        self.children[spec.name] = child
        return child

    def pids(self) -> list[int]:
        return [c.pid for c in self.children.values()]

    RESTARTED_ROLES = ("robot", "leader")

    def check_restarts(self, now: float | None = None) -> list[str]:
        """Restart robot and leader processes that exited, under the policy. Returns log lines of what
        happened. Only an exit (the child's PID is gone) restarts a process: never a lapsed liveliness
        token (a robot behind a network cut, or stopped, is still running: a second copy would fight it)."""
        now = time.monotonic() if now is None else now
        notes = []
        pol = self.plan.restart
        for name, c in list(self.children.items()):
            if c.spec.role not in self.RESTARTED_ROLES or c.given_up or c.scheduled or c.proc.poll() is None:
                continue
            rc = c.proc.returncode
            if rc == REFUSED_EXIT:  # it refused the run: a new copy would refuse it again
                c.given_up = True
                said = last_error(c.log)
                line = f"{name} refused to go on ({said or exit_text(rc)}; log: {c.log})"
                self.fatal = self.fatal or line  # the first one ends the run; each is said once
                notes.append(line)
                continue
            while c.restarts and now - c.restarts[0] > pol.window_s:
                c.restarts.popleft()
            if len(c.restarts) >= pol.max_restarts:
                c.given_up = True
                notes.append(f"{name} exited ({exit_text(rc)}); restarted {len(c.restarts)} times in "
                             f"{pol.window_s:g} s, giving up on it (log: {c.log})")
                continue
            c.restarts.append(now)
            if c.spec.role == "leader":
                self.leader_restarted += 1
            else:
                self.restarted += 1
            self.start(c.spec)
            notes.append(f"{name} exited ({exit_text(rc)}); restarted (log: {c.log})")
        return notes

    def fault(self, name: str, action: str) -> str:
        """A scheduled process fault (swarm.launch.process_faults): "kill" (SIGKILL, waited for; never
        restarted by the policy), "start" (a new process for the same spec; not counted as a restart),
        "stop" (SIGSTOP), "cont" (SIGCONT). Returns what was done, for the log."""
        c = self.children.get(name)
        if c is None:
            return f"{name}: no such process"
        if action == "kill":
            c.scheduled = True
            self.signal(name, signal.SIGKILL)
            try:
                c.proc.wait(2.0)
            except subprocess.TimeoutExpired:
                pass
            return f"{name} killed (SIGKILL, pid {c.pid})"
        if action == "start":
            new = self.start(c.spec)
            return f"{name}'s new process started (pid {new.pid}; it rejoins at its scheduled restart)"
        sig = {"stop": signal.SIGSTOP, "cont": signal.SIGCONT}[action]
        self.signal(name, sig)
        return f"{name} {'stopped (SIGSTOP' if action == 'stop' else 'resumed (SIGCONT'}, pid {c.pid})"

    def signal(self, name: str, sig: int) -> None:
        c = self.children.get(name)
        if c is not None and c.proc.poll() is None:
            try:
                os.killpg(c.pid, sig)
            except ProcessLookupError:
                pass

    def wait(self, name: str, timeout_s: float) -> int | None:
        c = self.children.get(name)
        if c is None:
            return None
        try:
            return c.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def shutdown(self, first: tuple[str, ...] = ()) -> None:
        """SIGTERM every child's group (`first` ones first, the router last), SIGKILL after the grace."""
        order = [n for n in first if n in self.children]
        order += [n for n in self.children if n not in order and n != "router"]
        if "router" in self.children:
            order.append("router")
        for n in order:
            self.signal(n, signal.SIGTERM)
            self.signal(n, signal.SIGCONT)  # a stopped process (a scheduled hang) acts on it only once resumed
            if n == "router":
                self.wait(n, self.grace_s)
        end = time.monotonic() + self.grace_s
        for n in order:
            c = self.children[n]
            try:
                c.proc.wait(max(0.0, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        for n in order:
            c = self.children[n]
            if c.proc.poll() is None:
                self.signal(n, signal.SIGKILL)
            try:
                os.killpg(c.pid, signal.SIGKILL)  # anything the child itself left in its group
            except (ProcessLookupError, PermissionError):
                pass
            try:
                c.proc.wait(2.0)
            except subprocess.TimeoutExpired:
                pass


REFUSED_EXIT = 4  # swarm.cli.common.EXIT_REFUSED: a process that refuses its run is not restarted


def last_error(log: Path) -> str:
    """The last line of a child's log that says why it stopped ("swarm robot: error: ..."), "" if none."""
    try:
        with open(log, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 8192))
            lines = f.read().decode("utf-8", "replace").splitlines()
    except OSError:
        return ""
    for line in reversed(lines):
        for mark in (": refused: ", ": error: ", ": failed: "):
            if mark in line:
                return line.split(mark, 1)[1].strip()
    return ""


def exit_text(rc: int | None) -> str:
    if rc is None:
        return "running"
    if rc < 0:
        try:
            return f"killed by {signal.Signals(-rc).name}"
        except ValueError:
            return f"killed by signal {-rc}"
    return f"exit code {rc}"

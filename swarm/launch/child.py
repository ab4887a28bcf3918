"""How a launcher stops a child it started (each leads its own process group); what the child does to itself is
swarm.process."""

from __future__ import annotations

import os
import signal


def stop_group(proc, term_s: float = 10.0, descendants: bool = False) -> None:
    """Stop a child that leads its own process group (started with process_group=0): SIGTERM to the group,
    and if the child has not ended within term_s, SIGKILL to it (with descendants, first to the group of
    every process it started: swarm up's children lead groups of their own), then reap it."""
    import subprocess

    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    try:
        proc.wait(term_s)
        return
    except subprocess.TimeoutExpired:
        pass
    if descendants:
        import psutil

        try:
            left = psutil.Process(proc.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            left = []
        for p in left:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        proc.wait(5.0)
    except subprocess.TimeoutExpired:
        pass

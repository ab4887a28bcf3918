"""`swarm router`: a zenoh router in this process (what `swarm up` embeds; several connect across machines)."""

from __future__ import annotations

import logging
import os
import time

from swarm.cli.common import (CHILD_EXIT_AFTER_S, EXIT_INTERRUPTED, StopEvent, check_endpoint, fleet_of,
                              open_bus, setup_logging)
from swarm.process import die_with_parent
from swarm.launch.plan import DEFAULT_LISTEN
from swarm.net import presence

log = logging.getLogger("swarm")

TRIM_STEP = 4 << 20  # bytes: resident memory this far above its base (the start, or what stayed in use) trims
TRIM_IDLE = 10  # trims in a row that freed nothing (5 s of looks): the memory is in use, it becomes the base


def cmd_router(args, started: float) -> int:

    die_with_parent()
    setup_logging()
    default = None if args.secure else [DEFAULT_LISTEN]  # --secure: the router identity's own endpoints
    listen = [check_endpoint("--listen", ep) for ep in (args.listen or default or [])] or None
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, mode="router", listen=listen, role="router")
        try:
            presence.announce(bus, fleet_of(args), "router")
            log.info("router listening on %s%s", ", ".join(listen or ["its identity's endpoints"]),
                     f" (mutual TLS, access control from {args.secure})" if args.secure else "")
            trim = HeapTrim()
            while not stop.wait(0.5):
                trim.check()
        finally:
            bus.close()
    return EXIT_INTERRUPTED


class HeapTrim:
    """Hands the heap that zenoh freed back to the system once resident memory has grown by TRIM_STEP.

    zenoh receives a large message in thousands of batch-sized buffers (4 KiB: swarm.net.bus.zenoh_config),
    allocated and freed on its receiving threads, and glibc keeps what they freed in its per-thread arenas:
    12 refused puts of 64 MiB (each cut off at zenoh's max_message_size) left the router 19-50 MiB larger for
    good; with these trims 1-28 MiB (bench/router_memory.py, 10 runs each). A look costs one read of
    /proc/self/statm; a trim (malloc_trim(0)) 0.1-5 ms of this thread, 16 ms with 120 MiB to give back, and
    only while resident memory is up. Nothing where the C library has no malloc_trim (musl, macOS) or there
    is no /proc."""

    def __init__(self) -> None:
        self.trim = _malloc_trim()
        self.page = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
        self.base = self.rss()
        self.idle = 0  # trims in a row that freed less than 1 MiB

    def rss(self) -> int | None:
        try:
            with open("/proc/self/statm", "rb") as f:
                return int(f.read().split()[1]) * self.page
        except (OSError, ValueError, IndexError):
            return None

    def check(self) -> None:
        """One look (the router's loop, every 0.5 s): trim while resident memory is TRIM_STEP above the base,
        until it is back near it; when TRIM_IDLE trims in a row freed nothing, what is resident is in use."""
        if self.trim is None or self.base is None:
            return
        now = self.rss()
        if now is None or now < self.base + TRIM_STEP:
            self.idle = 0
            return
        if self.idle >= TRIM_IDLE:
            self.base, self.idle = now, 0
            return
        t0 = time.perf_counter()
        self.trim(0)
        after = self.rss() or now
        self.idle = self.idle + 1 if now - after < 1 << 20 else 0
        log.debug("resident memory %.1f MiB: freed heap handed back in %.2f ms, %.1f MiB left", now / 2**20,
                  (time.perf_counter() - t0) * 1e3, after / 2**20)


def _malloc_trim():
    """glibc's malloc_trim, or None where the C library has none."""
    try:
        import ctypes

        fn = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError, ImportError):
        return None
    fn.argtypes, fn.restype = [ctypes.c_size_t], ctypes.c_int
    return fn

"""Helpers of the ROS 2 tests: a free loopback port, a bounded wait that names what it waited for,
and a thread-safe collector for bus callbacks."""

from __future__ import annotations

import socket
import threading
import time
from typing import Callable


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(pred: Callable[[], object], timeout_s: float, what: str, poke: Callable[[], None] | None = None,
               every_s: float = 0.02):
    """pred()'s first truthy value within timeout_s (poke() between tries: a new zenoh subscription
    reaches the router asynchronously, so a first message may need repeating); AssertionError naming
    `what` otherwise."""
    end = time.monotonic() + timeout_s
    while True:
        got = pred()
        if got:
            return got
        if time.monotonic() >= end:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        if poke is not None:
            poke()
        time.sleep(every_s)


class Collector:
    """A thread-safe list fed by bus callbacks."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.items: list = []

    def add(self, *item) -> None:
        with self.lock:
            self.items.append(item if len(item) != 1 else item[0])

    def snapshot(self) -> list:
        with self.lock:
            return list(self.items)

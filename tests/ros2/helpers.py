"""Helpers of the ROS 2 tests: a free loopback port, a bounded wait that names what it waited for,
and a thread-safe collector for bus callbacks."""

from __future__ import annotations

import threading

from tests.integration.helpers import free_port, wait_until  # noqa: F401  (shared by the ROS 2 tests)


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

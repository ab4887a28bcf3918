"""Fixtures of the ROS 2 tests: a zenoh router on loopback (a free port, multicast off) and clients
of it that are closed after each test."""

from __future__ import annotations

from typing import Callable, Iterator

import pytest

from swarm.net import bus as busmod
from tests.ros2.helpers import free_port


@pytest.fixture(scope="module")
def router() -> Iterator[str]:
    """A zenoh router in this process listening on a free loopback port; yields its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    r = busmod.ZenohBus(busmod.zenoh_config("router", listen=[endpoint]))
    try:
        yield endpoint
    finally:
        r.close()


@pytest.fixture
def client(router: str) -> Iterator[Callable[[], busmod.ZenohBus]]:
    """client() -> a new ZenohBus client of the router, closed when the test ends."""
    opened: list[busmod.ZenohBus] = []

    def make() -> busmod.ZenohBus:
        b = busmod.ZenohBus(busmod.zenoh_config("client", connect=[router]))
        opened.append(b)
        return b

    try:
        yield make
    finally:
        for b in reversed(opened):
            b.close()

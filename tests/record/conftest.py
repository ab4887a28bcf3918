"""Shared runs of the recording tests: a small `swarm sim` run and a small in-process swarm, each
recorded once per session (a few seconds in all)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from swarm.proto import keys, protocol
from swarm.view import record
from swarm.core import scenario_file as sf
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.core.sim import Result, Simulation

FLEET = "rec"


def small_scenario(robots: int = 5, duration: float = 3.0):
    """paper-50hz (dt = 0.02 s) with a few robots: freezes happen in the first seconds."""
    return sf.load("paper-50hz", sf.Overrides(robots=robots, duration=duration, seed=1))


@dataclass
class SimRun:
    scenario: object
    result: Result
    path: Path


@dataclass
class LiveRun:
    scenario: object
    metrics: dict
    world: object
    bus_recorder: record.BusRecorder
    path: Path
    snapshots: list  # every snapshot that went over the bus, decoded by a separate subscriber


@pytest.fixture(scope="session")
def sim_run(tmp_path_factory) -> SimRun:
    scn = small_scenario()
    result = Simulation(scn, record_period=record.record_period(20.0, scn.dt)).run()
    path = tmp_path_factory.mktemp("sim") / "sim.mcap"
    record.record_simulation(path, scn, result, 20.0)
    return SimRun(scn, result, path)


def run_recorded_swarm(scn, path: Path, record_hz: float | None = 20.0, commands_from_snapshots: bool = False) -> LiveRun:
    """tests/runtime/harness.run_swarm (world, leader and agents as threads on one in-memory net) with a
    BusRecorder on that net, subscribed before anything starts, closed with the world's metrics."""
    from tests.runtime import harness

    net = MemoryNet()
    rec = record.Recorder(path, scn, record_hz, source="lockstep", fleet=FLEET)
    br = record.BusRecorder(MemoryBus(net), FLEET, rec, commands_from_snapshots=commands_from_snapshots)
    seen: list = []
    MemoryBus(net).subscribe(keys.world_snapshot(FLEET), lambda k, b: seen.append(protocol.decode(b, "snapshot")))
    metrics, world, _agents = harness.run_swarm(scn, fleet=FLEET, net=net)
    br.close(metrics)
    return LiveRun(scn, metrics, world, br, path, seen)


@pytest.fixture(scope="session")
def live_run(tmp_path_factory) -> LiveRun:
    return run_recorded_swarm(small_scenario(), tmp_path_factory.mktemp("live") / "live.mcap")


@pytest.fixture(scope="session")
def live_run_lean(tmp_path_factory) -> LiveRun:
    """As live_run, with the commands taken from the world's snapshots (what `swarm up` does in lock-step)."""
    return run_recorded_swarm(small_scenario(), tmp_path_factory.mktemp("lean") / "lean.mcap",
                              commands_from_snapshots=True)

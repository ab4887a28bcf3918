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


# A hang of robot 2 (0.3-0.9 s), robot 4 killed at 0.4 s (for good), robots 2-4 cut off from 0.5 to 1.5 s,
# and a fifth of the neighbour states lost (stale neighbour data)
FAULTS_TOML = """[faults]
seed = 3
[[faults.drop]]
class = "state"
p = 0.2
[[faults.partition]]
groups = [[0, 1]]
start = 0.5
end = 1.5
[[faults.hang]]
robot = 2
at = 0.3
duration = 0.6
"""


def faulty_scenario(directory: Path):
    """small_scenario's 5 robots for 2 s with every kind of fault the viewer and the report show."""
    faults = directory / "faults.toml"
    faults.write_text(FAULTS_TOML)
    return sf.load("paper-50hz", sf.Overrides(robots=5, duration=2.0, seed=1, faults=str(faults), kill="4@0.4"))


@pytest.fixture(scope="session")
def sim_faults_run(tmp_path_factory) -> SimRun:
    d = tmp_path_factory.mktemp("simfaults")
    scn = faulty_scenario(d)
    result = Simulation(scn, record_period=record.record_period(20.0, scn.dt)).run()
    record.record_simulation(d / "sim.mcap", scn, result, 20.0)
    return SimRun(scn, result, d / "sim.mcap")


@pytest.fixture(scope="session")
def live_faults_run(tmp_path_factory) -> LiveRun:
    """The same faults in a lock-step swarm on one in-memory net (the world tells each fault on world/events)."""
    d = tmp_path_factory.mktemp("livefaults")
    return run_recorded_swarm(faulty_scenario(d), d / "live.mcap", commands_from_snapshots=True)


@pytest.fixture(scope="session")
def live_run(tmp_path_factory) -> LiveRun:
    return run_recorded_swarm(small_scenario(), tmp_path_factory.mktemp("live") / "live.mcap")


@pytest.fixture(scope="session")
def live_run_lean(tmp_path_factory) -> LiveRun:
    """As live_run, with the commands taken from the world's snapshots (what `swarm up` does in lock-step)."""
    return run_recorded_swarm(small_scenario(), tmp_path_factory.mktemp("lean") / "lean.mcap",
                              commands_from_snapshots=True)

"""The robot-side guard (agents.guard): a robot outside the arena is halted with a clear reason and
stays halted while it is outside; the other reasons still come first; on a fake clock, with a drive
that records what it is told."""

from __future__ import annotations

import math
import threading

import pytest

from agents.guard import Guard, arena_of
from swarm.core import runid, scenario_file
from swarm.core.clock import FakeClock
from swarm.drives.base import DriveBase

pytestmark = pytest.mark.unit


class Drive(DriveBase):
    """Records halts; `halted` as the real drives keep it (latched until send())."""

    def __init__(self) -> None:
        self.halted: str | None = None
        self.halts: list[str] = []

    def halt(self, reason: str) -> None:
        self.halted = reason
        self.halts.append(reason)

    def send(self) -> None:
        self.halted = None


ARENA = (-2.0, 2.0, -1.0, 1.0)


def test_outside_the_arena_halts_with_the_position_and_the_bounds():
    clock, drive = FakeClock(), Drive()
    g = Guard(drive, clock, arena=ARENA)
    g.pose(1.9, 0.0)
    assert g.check(0.0) is None and drive.halts == []
    g.pose(2.05, -0.5)
    why = g.check(0.1)
    assert why == "outside the arena: at (2.050, -0.500), beyond [-2, 2] x [-1, 1]"
    assert drive.halts == [why] and g.halts == 1
    g.pose(2.07, -0.51)  # it coasts on: the same reason (where it left), so one halt, latched
    assert g.check(0.15) == why and drive.halts == [why]
    drive.send()  # commanded again: the guard halts it again while it is outside
    g.pose(2.06, -0.5)
    assert g.check(0.2) == why and len(drive.halts) == 2
    g.pose(1.5, 0.5)  # a person carried it back
    assert g.check(0.3) is None
    g.pose(-2.5, 0.0)  # out again elsewhere: named where it left this time
    assert g.check(0.4).startswith("outside the arena: at (-2.500, 0.000)")


@pytest.mark.parametrize("x, y", [(-2.01, 0.0), (0.0, 1.01), (0.0, -1.5), (math.nan, 0.0), (0.0, math.inf)])
def test_every_side_and_non_finite_positions_are_outside(x, y):
    g = Guard(Drive(), FakeClock(), arena=ARENA)
    g.pose(x, y)
    assert g.reason(0.0).startswith("outside the arena")


def test_the_boundary_is_inside_and_no_arena_means_no_check():
    g = Guard(Drive(), FakeClock(), arena=ARENA)
    for x, y in ((-2.0, -1.0), (2.0, 1.0)):
        g.pose(x, y)
        assert g.reason(0.0) is None
    free = Guard(Drive(), FakeClock())
    free.pose(1e5, 1e5)
    assert free.reason(0.0) is None
    old = Guard(Drive(), FakeClock(), arena=ARENA)
    old.pose()  # a caller that gives no position: nothing to check
    assert old.reason(0.0) is None


def test_other_reasons_come_first():
    clock = FakeClock()
    g = Guard(Drive(), clock, pose_timeout_s=0.5, arena=ARENA)
    g.pose(5.0, 5.0)
    g.estop(True, "a person")
    assert g.reason(0.0) == "emergency stop (a person)"
    g.estop(False, "")
    g.leader(True)
    g.leader(False)
    assert g.reason(0.0) == "the leader is lost"
    g.leader(True)
    clock.advance(0.6)
    assert g.reason(0.0) == "no pose for more than 0.5 s"


def test_the_thread_halts_a_robot_that_left_the_arena():
    drive = Drive()
    g = Guard(drive, arena=ARENA, period_s=0.01)
    g.pose(3.0, 0.0)
    g.start(lambda: 1.0)
    try:
        done = threading.Event()
        for _ in range(200):
            if drive.halts:
                done.set()
                break
            done.wait(0.01)
        assert drive.halts and drive.halts[0].startswith("outside the arena")
    finally:
        g.close()


def test_arena_of_a_configuration_and_bad_arenas(write_scenario, base_doc):
    base_doc["arena"] = {"bounds": [-10.0, 10.0, -5.0, 5.0]}
    scn = scenario_file.load(write_scenario(base_doc), progress=scenario_file.silent)
    assert arena_of(runid.robot_config(scn, 0, False)) == (-10.0, 10.0, -5.0, 5.0)
    base_doc.pop("arena")
    scn = scenario_file.load(write_scenario(base_doc, "free.toml"), progress=scenario_file.silent)
    assert arena_of(runid.robot_config(scn, 0, False)) is None
    with pytest.raises(ValueError, match="xmin < xmax"):
        Guard(Drive(), FakeClock(), arena=(1.0, 0.0, 0.0, 1.0))


def _halted_within(drive: Drive, seconds: float) -> bool:
    done = threading.Event()
    for _ in range(int(seconds / 0.01)):
        if drive.halts:
            return True
        done.wait(0.01)
    return bool(drive.halts)


def test_the_thread_halts_when_poses_stop_and_sleeps_while_they_come():
    """While poses come the thread checks about once a pose timeout, not every period_s (the control loop
    checks before every command); once they stop it halts the drive just past the timeout."""
    drive = Drive()
    g = Guard(drive, pose_timeout_s=0.3, period_s=0.01)
    checks = []
    check = g.check
    g.check = lambda t: checks.append(t) or check(t)
    g.pose(0.0, 0.0)
    g.start(lambda: None)
    try:
        stop = threading.Event()
        for _ in range(30):  # 0.6 s of poses every 20 ms
            g.pose(0.0, 0.0)
            stop.wait(0.02)
        assert not drive.halts
        assert 1 <= len(checks) <= 6  # every period_s (10 ms) would be about 60
        assert _halted_within(drive, 5.0)
        assert drive.halts == ["no pose for more than 0.3 s"]
    finally:
        g.close()


@pytest.mark.parametrize("event", ["estop", "leader", "world"])
def test_an_event_wakes_the_thread_at_once(event):
    """The emergency stop, or a lost token, halts the drive at once, though nothing can time out for long."""
    drive = Drive()
    g = Guard(drive, period_s=30.0)  # without the event, its next look would be 30 s away
    g.leader(True), g.world(True)
    g.start(lambda: None)
    try:
        stop = threading.Event()
        stop.wait(0.05)  # the thread is asleep
        assert not drive.halts
        {"estop": lambda: g.estop(True, "test"), "leader": lambda: g.leader(False),
         "world": lambda: g.world(False)}[event]()
        assert _halted_within(drive, 5.0)
        assert drive.halts == [{"estop": "emergency stop (test)", "leader": "the leader is lost",
                                "world": "the world is lost"}[event]]
    finally:
        g.close()


def test_next_check_is_the_nearer_timeout_within_its_bounds():
    clock = FakeClock()
    g = Guard(Drive(), clock, pose_timeout_s=0.5, ref_timeout_s=2.5, period_s=0.05)
    assert g.next_check(None) == pytest.approx(1.0 + 1e-3)  # nothing known: MAX_IDLE_S
    g.pose(0.0, 0.0)
    clock.advance(0.2)
    assert g.next_check(None) == pytest.approx(0.3 + 1e-3)
    g.ref(10.0)
    assert g.next_check(12.4, rate=1.0) == pytest.approx(0.1 + 1e-3)
    assert g.next_check(12.4, rate=0.5) == pytest.approx(0.2 + 1e-3)  # half speed: twice the wall time
    clock.advance(0.3)
    assert g.next_check(None) == 0.05  # past it: at least period_s
    assert g.next_check(float("nan")) == 0.05
